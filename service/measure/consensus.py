"""Which section points belong to the shaft, before any fit: the geometry decides between the
stripe and what else drew lines in the image (a ghost reflection, a bright machine edge, a
chip's glint).

The stripe of a cylinder cut by the calibrated plane projects onto the section as a circle
about the shaft's axis; a ghost, an edge or a glint does not lie on it. With the axis known
(method ``axis``) the circle's centre is known and only its radius is sought: the ring about
the centre that holds the most points (``ring_consensus``). Without it (``geometric``), RANSAC
over circles through three points (``circle_consensus``). Either way whole chains of linked
image centres are judged together (``by_chain``): a chain that mostly lies off the circle is
something else crossing it, unless a long stretch of it lies on the circle.

Pure functions: section coordinates in mm, no I/O.
"""

from __future__ import annotations

import numpy as np

from service.measure import circle_kernels as ck


def ring_consensus(section_mm: np.ndarray, center_mm: np.ndarray, window_mm: float,
                   scatter_sigmas: float = 4.0) -> np.ndarray:
    """The points within ``window_mm`` of the radius about ``center_mm`` that most points
    share, the window widened to ``scatter_sigmas`` of the ring's own radial scatter where
    that is wider.

    A thick light sheet under speckle scatters the stripe's points by tens of micrometres:
    a fixed window then cuts the tails of the stripe's own scatter, one frame more on one
    side, another on the other, which moves the fitted radius by more than the points left
    inside show (at a sheet sigma of 0.15 mm a 50 um window dropped 14 % of the points and
    the reported uncertainty fell a quarter short of the diameter's scatter).

    Parameters
    ----------
    section_mm : ndarray, shape (N, 2)
        Section points, mm.
    center_mm : ndarray, shape (2,)
        The section's centre (the spindle axis), mm.
    window_mm : float
        Least half-width of the ring, mm: the stripe's own radial scatter plus how far the
        centre may be off.
    scatter_sigmas : float
        Half-width of the ring in robust standard deviations of its points' radii about
        its radius, when that is wider than ``window_mm``; 0 keeps ``window_mm``.

    Returns
    -------
    ndarray of bool, shape (N,)
        The ring's points (all False for no points).
    """
    n = len(section_mm)
    if n == 0:
        return np.zeros(0, bool)
    # Compiled (circle_kernels.ring_consensus): the radii sorted, the window [s_i, s_i + 2 w]
    # holding the most of them, the ring's radius their median, the window widened to the
    # scatter about it while a cut sample understates it (three times at most).
    return ck.ring_consensus(np.ascontiguousarray(section_mm, np.float64),
                             float(center_mm[0]), float(center_mm[1]), float(window_mm),
                             float(scatter_sigmas))


def circle_consensus(section_mm: np.ndarray, tol_mm: float, max_radius_mm: float,
                     hypotheses: int = 100, seed: int = 0) -> np.ndarray:
    """RANSAC: the points within ``tol_mm`` of the circle through three of them that most
    points lie near.

    Parameters
    ----------
    section_mm : ndarray, shape (N, 2)
        Section points, mm.
    tol_mm : float
        Distance from a circle within which a point supports it, mm.
    max_radius_mm : float
        Circles larger than this are not a shaft.
    hypotheses : int
        Circles tried (100: with half the points on the circle, all 100 miss it once in
        600 000 frames).
    seed : int
        Seed of the draws (the same points always give the same answer).

    Returns
    -------
    ndarray of bool, shape (N,)
        The best circle's points (all True when there are fewer than 3 points or no circle
        was found: the fit decides then).
    """
    n = len(section_mm)
    if n < 3:
        return np.ones(n, bool)
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, n, (hypotheses, 3))
    a, b, c = section_mm[idx[:, 0]], section_mm[idx[:, 1]], section_mm[idx[:, 2]]
    # The circumcentre of each triple.
    d = 2.0 * (a[:, 0] * (b[:, 1] - c[:, 1]) + b[:, 0] * (c[:, 1] - a[:, 1])
               + c[:, 0] * (a[:, 1] - b[:, 1]))
    ok = np.abs(d) > 1e-12
    a2, b2, c2 = (a**2).sum(1), (b**2).sum(1), (c**2).sum(1)
    with np.errstate(divide="ignore", invalid="ignore"):
        ux = (a2 * (b[:, 1] - c[:, 1]) + b2 * (c[:, 1] - a[:, 1]) + c2 * (a[:, 1] - b[:, 1])) / d
        uy = (a2 * (c[:, 0] - b[:, 0]) + b2 * (a[:, 0] - c[:, 0]) + c2 * (b[:, 0] - a[:, 0])) / d
    r = np.hypot(a[:, 0] - ux, a[:, 1] - uy)
    ok &= np.isfinite(r) & (r <= max_radius_mm)
    if not ok.any():
        return np.ones(n, bool)
    ux, uy, r = ux[ok], uy[ok], r[ok]
    dist = np.abs(np.hypot(section_mm[None, :, 0] - ux[:, None],
                           section_mm[None, :, 1] - uy[:, None]) - r[:, None])
    support = dist <= tol_mm
    return support[int(np.argmax(support.sum(axis=1)))]


def by_chain(inside: np.ndarray, chain: np.ndarray | None, min_share: float = 0.5,
             min_on_circle: int = 30) -> np.ndarray:
    """``inside``, less the points of chains of which fewer than ``min_share`` are inside,
    unless ``min_on_circle`` or more are.

    A line crossing the circle (a lit edge, a ghost's chain) has a handful of its points on
    it, where it crosses; a long stretch of a chain on the circle is the stripe, whatever
    else the chain runs into (a large coolant drop's bright rim links to the stripe on both
    sides of the drop and can make most of the chain).

    Parameters
    ----------
    inside : ndarray of bool, shape (N,)
        Points on the shaft's circle.
    chain : ndarray of int, shape (N,), or None
        Each point's chain label (``StripePoints.chain``); None judges points alone.
    min_share : float
        Least share of a chain's points on the circle for the chain to count.
    min_on_circle : int
        ... or least number of its points on the circle.
    """
    if chain is None or len(chain) == 0:
        return inside
    # Labels are point indices (``steger_kernels.chain_labels``): counted as they are, with
    # no sort; any other labels are numbered first.
    labels = chain if chain.min() >= 0 and chain.max() < 4 * len(chain) + 1024 else \
        np.unique(chain, return_inverse=True)[1]
    return ck.by_chain(np.ascontiguousarray(inside, np.bool_),
                       np.ascontiguousarray(labels, np.int64), float(min_share),
                       int(min_on_circle))
