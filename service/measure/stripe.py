"""Laser stripe centres to sub-pixel precision: a cheap coarse band, then Steger's method.

Steger (1998) finds the centre of a bright line along its local normal ``n``, the eigenvector of
the Hessian of the Gaussian-smoothed image with the most negative eigenvalue::

    t = -(n . g) / (n^T H n),   centre = pixel + t n,   accepted when |t nx|, |t ny| <= 0.5

Only pixels inside a band around the stripe, found on a 4x-decimated image, are examined, so the
cost scales with the stripe, not the frame. Each centre carries a *strength* (the curvature
across the line, grey levels / px^2) and a *width* (the stripe's own Gaussian sigma, px), so
that weak or smeared points can be rejected or down-weighted.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import cv2
import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

# Robust standard deviation from the median absolute deviation of a normal sample.
_MAD_TO_SIGMA = 1.4826
# Steger accepts a centre within half a pixel; a line exactly on a pixel boundary would be lost
# to float rounding in both neighbours, so allow a hair more (a duplicate is harmless).
_HALF_PIXEL = 0.5 + 1e-3
# First-step window: wide enough that the pixel nearest a centre is always a candidate.
_SEARCH = 0.6


@dataclass(frozen=True)
class StripeParams:
    """Settings of the stripe extractor.

    Attributes
    ----------
    sigma_px : float
        Gaussian scale of the derivative filters, px. Steger: at least ``w / sqrt(3)`` for a
        stripe of half-width ``w``.
    decimation : int
        Down-sampling factor of the coarse pass.
    min_contrast : float
        Least stripe peak above background, as a fraction of the image's full scale (255 for
        8-bit, 65535 for 16-bit), for a frame to hold a stripe at all.
    coarse_fraction : float
        Coarse threshold between background (0) and peak (1).
    band_px : int
        Half-width, in full-resolution px, of the band kept around the coarse stripe.
    min_strength_sigma : float
        A centre's curvature must exceed this many standard deviations of the curvature that
        the image noise alone produces.
    min_relative_strength : float
        ... and this fraction of the 90th percentile of the centres' curvatures (weak tails).
    width_range : tuple of float
        Accepted stripe width relative to the median width (smeared or split points outside).
    link_gap_px : float
        Centres closer than this belong to the same line (Steger's linking).
    min_chain : int
        Shortest line, in centres, that is kept: shorter chains are noise or specks.
    curvature_correction : bool
        Undo the shift of a curved stripe's smoothed ridge toward its centre of curvature
        (``correct_curvature_bias``).
    curvature_window_px : float
        Gaussian half-width along the stripe of the local parabola that measures curvature, px.
    optics_blur_px : float
        Gaussian blur (sigma) of the lens, px: blur bends a curved stripe inward too. 0.7 px
        is typical of a well-focused machine-vision lens; set it from your lens.
    background_px : int
        Diameter of the disc whose morphological opening estimates the local background (light
        on the part around the stripe), which is subtracted before the derivatives: a
        background sloping across the stripe shifts Steger's centre by slope / curvature,
        most where the stripe is weak. 0 subtracts nothing.
    """

    sigma_px: float = 1.5
    decimation: int = 4
    min_contrast: float = 0.06
    coarse_fraction: float = 0.2
    band_px: int = 10
    min_strength_sigma: float = 6.0
    min_relative_strength: float = 0.08
    width_range: tuple[float, float] = (0.4, 2.5)
    link_gap_px: float = 2.0
    min_chain: int = 10
    curvature_correction: bool = True
    curvature_window_px: float = 5.0
    optics_blur_px: float = 0.7
    background_px: int = 11


@dataclass(frozen=True)
class StripePoints:
    """Sub-pixel stripe centres of one image.

    Attributes
    ----------
    xy : ndarray, shape (N, 2)
        Centres (x, y) in pixels, OpenCV convention (pixel centres at integers).
    normal : ndarray, shape (N, 2)
        Unit normal of the stripe at each centre.
    strength : ndarray, shape (N,)
        Curvature across the stripe, grey levels per px^2 (larger is stronger).
    width_px : ndarray, shape (N,)
        Estimated Gaussian sigma of the stripe profile, px.
    background : float
        Background grey level of the image.
    noise : float
        Robust standard deviation of the background, grey levels.
    reason : str
        Why there are no points, when there are none.
    peak : ndarray, shape (N,), or None
        Height of the smoothed profile above the background at each centre, grey levels:
        ``peak / strength`` is ``w^2 + s^2``, and sums of both over many points give a width
        that the noise does not inflate.
    """

    xy: np.ndarray
    normal: np.ndarray
    strength: np.ndarray
    width_px: np.ndarray
    background: float = 0.0
    noise: float = 0.0
    reason: str = ""
    peak: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.xy.shape[0])

    def __bool__(self) -> bool:
        return len(self) > 0

    def subset(self, keep: np.ndarray) -> StripePoints:
        """The points selected by a boolean mask or index array."""
        return StripePoints(
            self.xy[keep], self.normal[keep], self.strength[keep], self.width_px[keep],
            self.background, self.noise, self.reason,
            None if self.peak is None else self.peak[keep],
        )

    @classmethod
    def empty(cls, reason: str, background: float = 0.0, noise: float = 0.0) -> StripePoints:
        """No centres, and why."""
        z = np.empty((0,))
        return cls(np.empty((0, 2)), np.empty((0, 2)), z, z, background, noise, reason)


def full_scale(image: np.ndarray) -> float:
    """Largest grey level the image's dtype can hold (1.0 for float images)."""
    if np.issubdtype(image.dtype, np.integer):
        return float(np.iinfo(image.dtype).max)
    return 1.0


def coarse_band(
    image: np.ndarray, params: StripeParams
) -> tuple[np.ndarray | None, float, float, str]:
    """Find a band around the stripe on a decimated copy of the image.

    Parameters
    ----------
    image : ndarray, shape (H, W)
        Grey image, any numeric dtype.
    params : StripeParams
        Extractor settings.

    Returns
    -------
    band : ndarray of bool, shape (H, W), or None
        True inside the band; None when the image holds no stripe.
    background : float
        Median grey level.
    noise : float
        Robust standard deviation of the grey levels of the decimated image's dark part.
    reason : str
        Why there is no band, when ``band`` is None.
    """
    h, w = image.shape
    k = max(1, int(params.decimation))
    small = cv2.resize(image.astype(np.float32), (max(1, w // k), max(1, h // k)),
                       interpolation=cv2.INTER_AREA)
    background = float(np.median(small))
    dark = small[small <= np.percentile(small, 75)]
    noise = _MAD_TO_SIGMA * float(np.median(np.abs(dark - np.median(dark)))) * k
    peak = float(cv2.GaussianBlur(small, (3, 3), 0).max())
    contrast = peak - background
    if contrast < params.min_contrast * full_scale(image):
        return None, background, noise, (
            f"no stripe: peak {peak:.1f} is only {contrast:.1f} grey levels above the background"
            f" {background:.1f} (need {params.min_contrast * full_scale(image):.1f})"
        )
    threshold = background + max(params.coarse_fraction * contrast, 4.0 * noise / k)
    mask = (small > threshold).astype(np.uint8)
    _, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    # Drop specks (hot pixels, glints) of a few decimated pixels.
    big = np.flatnonzero(stats[1:, cv2.CC_STAT_AREA] >= 3) + 1
    if big.size == 0:
        return None, background, noise, "no stripe: no bright structure larger than a speck"
    mask = np.isin(labels, big).astype(np.uint8)
    radius = max(1, math.ceil(params.band_px / k))
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
    mask = cv2.dilate(mask, kernel)
    band = cv2.resize(mask, (w, h), interpolation=cv2.INTER_NEAREST).astype(bool)
    return band, background, noise, ""


def _gaussian_kernels(sigma: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sampled Gaussian and its first two derivatives, normalised on the sampled support."""
    r = max(1, math.ceil(4.0 * sigma))
    x = np.arange(-r, r + 1, dtype=np.float64)
    g = np.exp(-0.5 * (x / sigma) ** 2)
    g /= g.sum()
    g1 = x / sigma**2 * g             # cv2 filters correlate: +x, not the textbook -x
    g1 /= (x * g1).sum()             # unit response to a unit ramp
    g2 = (x**2 / sigma**4 - 1.0 / sigma**2) * g
    g2 -= g2.mean()                  # zero response to a constant
    g2 /= 0.5 * (x**2 * g2).sum()    # response 2 to x^2 (second derivative of x^2)
    return g.astype(np.float32), g1.astype(np.float32), g2.astype(np.float32)


def local_background(image: np.ndarray, disc_px: int) -> np.ndarray:
    """Smooth estimate of what lies under a thin bright line: the morphological opening by a
    disc wider than the line (it removes the line, keeps slower shading), then a Gaussian to
    take the opening's corners off, raised to the image's median level about it."""
    k = int(disc_px) | 1
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k))
    opened = cv2.morphologyEx(image, cv2.MORPH_OPEN, disc, borderType=cv2.BORDER_REPLICATE)
    smooth = cv2.GaussianBlur(opened, (0, 0), k / 4.0)
    # The opening of a noisy image lies below it by a good part of the noise (a minimum
    # filter comes first), which would add to every stripe height: put back the median
    # difference, which a thin stripe does not move (sampled: it is only a level).
    return smooth + np.float32(np.median((image - smooth)[::3, ::3]))


def _steger_step(d: dict[str, np.ndarray]) -> tuple[np.ndarray, ...]:
    """Hessian eigenvalues (low, high), the line normal and Steger's offset ``t`` along it."""
    half_tr = 0.5 * (d["xx"] + d["yy"])
    root = np.hypot(0.5 * (d["xx"] - d["yy"]), d["xy"])
    theta = 0.5 * np.arctan2(2.0 * d["xy"], d["xx"] - d["yy"])  # direction of the high one
    nx, ny = -np.sin(theta), np.cos(theta)                       # ... and of the low one
    lam_lo = half_tr - root
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -(nx * d["x"] + ny * d["y"]) / lam_lo
    return lam_lo, half_tr + root, nx, ny, t


def derivatives_at(image: np.ndarray, x: np.ndarray, y: np.ndarray, sigma: float
                   ) -> dict[str, np.ndarray]:
    """The Gaussian-smoothed image and its derivatives up to second order at float positions.

    Each value is the image convolved with the continuous Gaussian (or its derivative) centred
    at ``(x, y)`` itself, summed over the pixels around it, not interpolated between the
    filtered images' pixels: the smoothed profile of a 1 px stripe changes too fast for that,
    and interpolated derivatives (bilinear or cubic) put Steger's centre up to 0.014 px off,
    depending on where the stripe falls between pixels (pixel locking).

    Parameters
    ----------
    image : ndarray, shape (H, W)
        Grey image (float).
    x, y : ndarray, shape (N,)
        Positions, px; within the image, ``4 sigma + 1`` px from its border (else clamped).
    sigma : float
        Gaussian scale, px.

    Returns
    -------
    dict of ndarray
        ``v, x, y, xx, xy, yy``: value, gradient and Hessian at each position.
    """
    h, w = image.shape
    r = max(1, math.ceil(4.0 * sigma))
    cx = np.clip(np.rint(x).astype(np.intp), r, w - 1 - r)
    cy = np.clip(np.rint(y).astype(np.intp), r, h - 1 - r)
    k = np.arange(-r, r + 1)
    patch = image[(cy[:, None] + k)[:, :, None], (cx[:, None] + k)[:, None, :]]

    def kernels(d: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        u = (k[None, :] - d[:, None]) / sigma          # sample position relative to the point
        g = np.exp(-0.5 * u * u) / (math.sqrt(2 * math.pi) * sigma)
        return g, u / sigma * g, (u * u - 1.0) / sigma**2 * g  # G, dG/dpoint, d2G

    gy, gy1, gy2 = kernels(y - cy)
    # Along x first, the three kernels at once (a batched product), then along y.
    along_x = np.matmul(patch.astype(np.float64), np.stack(kernels(x - cx), axis=-1))
    sx, sx1, sx2 = along_x[..., 0], along_x[..., 1], along_x[..., 2]

    def along_y(ky: np.ndarray, row: np.ndarray) -> np.ndarray:
        return np.einsum("ni,ni->n", ky, row)

    return {"v": along_y(gy, sx), "x": along_y(gy, sx1), "y": along_y(gy1, sx),
            "xx": along_y(gy, sx2), "yy": along_y(gy2, sx), "xy": along_y(gy1, sx1)}


def steger_centres(
    image: np.ndarray, band: np.ndarray | None, params: StripeParams,
    background: float = 0.0, noise: float = 0.0,
) -> StripePoints:
    """Steger's sub-pixel line centres inside ``band`` (the whole image when None).

    Parameters
    ----------
    image : ndarray, shape (H, W)
        Grey image.
    band : ndarray of bool or None
        Pixels to examine.
    params : StripeParams
        Extractor settings.
    background, noise : float
        Background grey level and its noise (grey levels), for strength and width.

    Returns
    -------
    StripePoints
        All accepted centres, unsorted.
    """
    h, w = image.shape
    s = float(params.sigma_px)
    r = max(1, math.ceil(4.0 * s))
    if band is None:
        y0, y1, x0, x1 = 0, h, 0, w
    else:
        ys, xs = np.nonzero(band.any(axis=1))[0], np.nonzero(band.any(axis=0))[0]
        if ys.size == 0:
            return StripePoints.empty("no stripe: empty band", background, noise)
        y0, y1 = max(0, ys[0] - r), min(h, ys[-1] + r + 1)
        x0, x1 = max(0, xs[0] - r), min(w, xs[-1] + r + 1)
    roi = image[y0:y1, x0:x1].astype(np.float32)
    if params.background_px > 0:
        roi = roi - local_background(roi, params.background_px) + np.float32(background)
    g, g1, g2 = _gaussian_kernels(s)

    def filt(kx: np.ndarray, ky: np.ndarray) -> np.ndarray:
        return cv2.sepFilter2D(roi, cv2.CV_32F, kx, ky, borderType=cv2.BORDER_REPLICATE)

    sel = np.ones(roi.shape, bool) if band is None else band[y0:y1, x0:x1].copy()
    # Centres need the full filter support inside the image.
    sel[: max(0, r - y0), :] = False
    sel[:, : max(0, r - x0)] = False
    if y1 > h - r:
        sel[roi.shape[0] - (y1 - (h - r)):, :] = False
    if x1 > w - r:
        sel[:, roi.shape[1] - (x1 - (w - r)):] = False
    iy, ix = np.nonzero(sel)
    if iy.size == 0:
        return StripePoints.empty("no stripe: band lies on the image border", background, noise)

    images = {
        "v": filt(g, g), "x": filt(g1, g), "y": filt(g, g1),
        "xx": filt(g2, g), "yy": filt(g, g2), "xy": filt(g1, g1),
    }
    at_pixels = {k: im[iy, ix].astype(np.float64) for k, im in images.items()}
    lam_lo, lam_hi, nx, ny, t = _steger_step(at_pixels)
    noise_curv = max(noise, 1e-6) * math.sqrt(3.0 / (16.0 * math.pi)) / s**3
    ok = (
        (lam_lo < 0) & (np.abs(lam_lo) > np.abs(lam_hi))
        & (np.abs(t * nx) <= _SEARCH) & (np.abs(t * ny) <= _SEARCH)
        & (-lam_lo > params.min_strength_sigma * noise_curv)
    )
    if not ok.any():
        return StripePoints.empty("no stripe: no line centre passed Steger's test", background,
                                  noise)
    iy, ix, nx, ny, t = iy[ok], ix[ok], nx[ok], ny[ok], t[ok]
    # One Newton refinement with the derivatives at the first estimate (evaluated there, not
    # interpolated): a single step from a pixel centre overshoots a Gaussian profile by up
    # to ~0.02 px.
    fx, fy = ix + t * nx, iy + t * ny
    at_centre = derivatives_at(roi, fx, fy, s)
    g_n = nx * at_centre["x"] + ny * at_centre["y"]
    h_nn = nx * nx * at_centre["xx"] + 2 * nx * ny * at_centre["xy"] + ny * ny * at_centre["yy"]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = t - g_n / h_nn
    keep = (np.abs(t * nx) <= _HALF_PIXEL) & (np.abs(t * ny) <= _HALF_PIXEL) & (h_nn < 0)
    ix, iy, nx, ny, t = ix[keep], iy[keep], nx[keep], ny[keep], t[keep]
    rv, strength = at_centre["v"][keep], -h_nn[keep]
    peak = rv - background
    px = ix + x0 + t * nx
    py = iy + y0 + t * ny
    # Smoothed profile of a Gaussian line of sigma w: V'' = -V / (w^2 + s^2) at the centre.
    with np.errstate(divide="ignore", invalid="ignore"):
        s_eff2 = (rv - background) / strength
    width = np.sqrt(np.clip(s_eff2 - s * s, 0.0, None))
    return StripePoints(
        xy=np.column_stack([px, py]), normal=np.column_stack([nx, ny]),
        strength=strength, width_px=width, background=background, noise=noise,
        peak=peak,
    )


def reject_weak(points: StripePoints, params: StripeParams) -> StripePoints:
    """Drop weak (low curvature) and smeared or split (odd width) centres."""
    if not points:
        return points
    keep = points.strength >= params.min_relative_strength * np.percentile(points.strength, 90)
    med_w = float(np.median(points.width_px[keep])) if keep.any() else 0.0
    if med_w > 0:
        lo, hi = params.width_range
        keep &= (points.width_px >= lo * med_w) & (points.width_px <= hi * med_w)
    return points.subset(keep)


def keep_long_chains(points: StripePoints, gap_px: float, min_chain: int) -> StripePoints:
    """Link centres closer than ``gap_px`` into lines; keep lines of ``min_chain`` or more.

    A laser stripe gives about one centre per pixel along its length, so its centres form long
    chains; noise and specks that pass Steger's test give isolated centres or short chains.
    """
    if len(points) == 0:
        return points
    pairs = cKDTree(points.xy).query_pairs(gap_px, output_type="ndarray")
    n = len(points)
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, labels = connected_components(graph, directed=False)
    sizes = np.bincount(labels)
    return points.subset(sizes[labels] >= min_chain)


def correct_curvature_bias(points: StripePoints, sigma_px: float, window_px: float = 5.0
                           ) -> StripePoints:
    """Move centres of a curved stripe back out of the curve.

    Smoothing a line that curves with curvature ``kappa`` with a Gaussian of scale ``s`` moves
    its ridge toward the centre of curvature by about ``s^2 kappa / 2`` (in polar form the heat
    equation has a drift term ``u_r / r``; the line's own width does not matter). Near the ends
    of the stripe on a shaft, where its image bends sharply, that is several hundredths of a
    pixel: micrometres that a short-arc fit amplifies tenfold. Here each centre's curvature
    comes from a parabola ``v = a + b u + c u^2`` fitted, with Gaussian weights along the
    stripe, to its neighbours in the frame of its own tangent ``u`` and normal ``v``
    (``kappa = 2c``); the centre then moves by ``-s^2 c`` along
    its normal.

    Parameters
    ----------
    points : StripePoints
        Centres from ``steger_centres``.
    sigma_px : float
        Total smoothing, px: the derivative filters' scale combined with any known lens blur.
    window_px : float
        Gaussian weight half-width along the stripe, px.

    Returns
    -------
    StripePoints
        The same points, moved.
    """
    n_pts = len(points)
    k = min(int(4 * window_px) + 1, n_pts)
    if k < 5:
        return points
    xy, nrm = points.xy, points.normal
    _, idx = cKDTree(xy).query(xy, k=k)
    rel = xy[idx] - xy[:, None, :]
    tangent = np.column_stack([-nrm[:, 1], nrm[:, 0]])
    u = np.einsum("nkj,nj->nk", rel, tangent)
    v = np.einsum("nkj,nj->nk", rel, nrm)
    design = np.stack([np.ones_like(u), u, u * u], axis=-1)
    wgt = np.exp(-0.5 * (u / window_px) ** 2) * (np.abs(v) < 2.0)  # skip a parallel stray line
    ata = np.einsum("nki,nk,nkj->nij", design, wgt, design) + 1e-9 * np.eye(3)
    atv = np.einsum("nki,nk,nk->ni", design, wgt, v)
    c = np.linalg.solve(ata, atv[..., None])[:, 2, 0]
    shift = -(sigma_px**2) * c
    # A parabola on too few neighbours (an isolated blob) says nothing: leave those points.
    shift[np.abs(shift) > 0.5] = 0.0
    return replace(points, xy=xy + shift[:, None] * nrm)


def extract_stripe(image: np.ndarray, params: StripeParams | None = None) -> StripePoints:
    """Sub-pixel centres of the laser stripe in a grey image.

    Parameters
    ----------
    image : ndarray, shape (H, W)
        Grey image (uint8, uint16 or float).
    params : StripeParams, optional
        Extractor settings.

    Returns
    -------
    StripePoints
        Centres in pixels; empty, with ``reason`` set, when the image holds no stripe.
    """
    params = params or StripeParams()
    if image.ndim != 2:
        return StripePoints.empty(f"expected a grey image, got shape {image.shape}")
    band, background, noise, reason = coarse_band(image, params)
    if band is None:
        return StripePoints.empty(reason, background, noise)
    points = reject_weak(steger_centres(image, band, params, background, noise), params)
    points = keep_long_chains(points, params.link_gap_px, params.min_chain)
    if not points:
        return StripePoints.empty("no stripe: no line of centres long enough", background,
                                  noise)
    if params.curvature_correction:
        smoothing = math.hypot(params.sigma_px, params.optics_blur_px)
        points = correct_curvature_bias(points, smoothing, params.curvature_window_px)
    return points
