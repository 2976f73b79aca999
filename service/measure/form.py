"""Form and position of the turning surface from many frames: run-out (the surface's centre
going round the spindle axis) and roundness (its radius over the material's angle).

Conventions. Section coordinates are the measurement's (``section.orthonormal_basis`` of the
calibration's ``axis.direction``: ``e1 x e2`` along the axis). Spindle angles count
right-handed about ``axis.direction``: at a larger angle the material has turned further that
way, so a point fixed in the material at angle ``beta`` (from ``e1`` toward ``e2``) stands at
``beta + theta`` at spindle angle ``theta``. A surface whose own axis lies ``e`` off the
spindle's, in the material's direction ``phi``, has its centre at

    c(theta) = axis + e (cos(phi + theta), sin(phi + theta))

and the dial indicator's total indicated run-out is ``2 e``. Its radius at the material's
angle ``beta`` is ``R + sum_k a_k cos(k beta - phase_k)`` (harmonic ``k``: ``k`` lobes).

Everything here is pure numerics: centres, covariances, points and angles in; figures with
their uncertainties out. Failures are values (``ok`` False, ``reason``), never exceptions.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from service.measure import circle_kernels as ck


def rotation(theta_rad: float) -> np.ndarray:
    """The 2x2 rotation by ``theta_rad`` (from ``e1`` toward ``e2``)."""
    c, s = math.cos(theta_rad), math.sin(theta_rad)
    return np.array([[c, -s], [s, c]])


def rotations(theta_rad: np.ndarray) -> np.ndarray:
    """The 2x2 rotations by each of ``theta_rad``, shape (N, 2, 2)."""
    c, s = np.cos(theta_rad), np.sin(theta_rad)
    return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)


@dataclass(frozen=True)
class Runout:
    """The surface's position relative to the spindle axis.

    Attributes
    ----------
    ok : bool
        Whether the fit was possible.
    eccentricity_mm, eccentricity_deg : float
        How far the surface's axis lies off the spindle's and in which material direction.
    tir_mm : float
        Total indicated run-out, ``2 e`` with the noise's share of ``e`` taken out: the
        length of a noisy vector overstates the true one (its square by the trace of its
        covariance), which on a concentric surface would read as run-out that is not there.
    eccentricity_uncertainty_mm, eccentricity_deg_uncertainty, tir_uncertainty_mm : float
        Standard uncertainties.
    axis_shift_mm : tuple of float
        Where the frames say the spindle axis lies relative to the axis given (the calibrated
        or tracked one), section mm; with ``axis_shift_cov``.
    chi2_per_dof : float
        How well the model explains the centres (about 1 when their covariances are right).
    parameter_cov : ndarray, shape (k, k)
        The fit's covariance of the eccentricity vector (e cos phi, e sin phi) and, when the
        axis was fitted, its shift (k = 4; else 2).
    frames : int
        Frames used.
    reason : str
        Why not, when ``ok`` is False.
    """

    ok: bool
    eccentricity_mm: float = math.nan
    eccentricity_deg: float = math.nan
    tir_mm: float = math.nan
    eccentricity_uncertainty_mm: float = math.nan
    eccentricity_deg_uncertainty: float = math.nan
    tir_uncertainty_mm: float = math.nan
    axis_shift_mm: tuple[float, float] = (math.nan, math.nan)
    axis_shift_cov: tuple[float, float, float] = (math.nan, math.nan, math.nan)
    chi2_per_dof: float = math.nan
    parameter_cov: np.ndarray = field(default_factory=lambda: np.full((2, 2), np.nan),
                                      repr=False)
    frames: int = 0
    reason: str = ""

    def center_at(self, axis: np.ndarray, spindle_deg: float) -> np.ndarray:
        """The surface's centre at a spindle angle (section mm), given the spindle axis."""
        phi = math.radians(self.eccentricity_deg + spindle_deg)
        return np.asarray(axis, np.float64) + np.asarray(self.axis_shift_mm) + \
            self.eccentricity_mm * np.array([math.cos(phi), math.sin(phi)])


def fit_runout(centres_mm: np.ndarray, covs_mm2: np.ndarray, spindle_deg: np.ndarray,
               axis_mm: np.ndarray, fit_axis: bool = True, min_span_deg: float = 180.0
               ) -> Runout:
    """The surface's eccentricity (and the spindle axis) from free-fit centres at known
    spindle angles, by weighted least squares.

    Parameters
    ----------
    centres_mm : ndarray, shape (N, 2)
        Each frame's free-fit centre, section mm.
    covs_mm2 : ndarray, shape (N, 2, 2)
        Their covariances: large along each arc's bisector, where centre and radius trade
        off; the weights use all of it.
    spindle_deg : ndarray, shape (N,)
        Each frame's spindle angle.
    axis_mm : ndarray, shape (2,)
        The spindle axis as calibrated (or tracked), section mm.
    fit_axis : bool
        Also estimate where the spindle axis lies (needs angles that go round: a fixed
        offset and a rotating one are otherwise the same thing); False keeps ``axis_mm``.
    min_span_deg : float
        With ``fit_axis``, the angles must cover at least this much of a revolution.

    Returns
    -------
    Runout
    """
    c = np.asarray(centres_mm, np.float64).reshape(-1, 2)
    cov = np.asarray(covs_mm2, np.float64).reshape(-1, 2, 2)
    th = np.radians(np.asarray(spindle_deg, np.float64).ravel())
    n = len(c)
    if n < (3 if fit_axis else 2) or len(cov) != n or len(th) != n:
        return Runout(False, frames=n, reason=f"{n} frames with a free fit, need "
                      f"{3 if fit_axis else 2} (and a covariance and an angle each)")
    span = span_deg(np.degrees(th))
    if fit_axis and span < min_span_deg:
        return Runout(False, frames=n, reason=f"the spindle angles cover {span:.0f} degrees, "
                      f"need {min_span_deg:.0f} to tell run-out from the axis")
    try:
        weights = np.linalg.inv(cov)
    except np.linalg.LinAlgError:
        return Runout(False, frames=n, reason="a frame's centre covariance is singular")
    k = 4 if fit_axis else 2
    d = c - np.asarray(axis_mm, np.float64)
    design = rotations(th)
    if fit_axis:
        design = np.concatenate([design, np.broadcast_to(np.eye(2), (n, 2, 2))], axis=2)
    wa = weights @ design
    normal = np.einsum("nji,njk->ik", design, wa)
    rhs = np.einsum("nji,nj->i", wa, d)
    try:
        p_cov = np.linalg.inv(normal)
    except np.linalg.LinAlgError:
        return Runout(False, frames=n, reason="the frames do not determine the run-out "
                      "(their angles and arcs leave it open)")
    p = p_cov @ rhs
    res = d - design @ p
    chi2 = float(np.einsum("ni,nij,nj->", res, weights, res))
    dof = max(2 * n - k, 1)
    ex, ey = p[0], p[1]
    e = math.hypot(ex, ey)
    e_cov = p_cov[:2, :2]
    if e > 0:
        u = np.array([ex, ey]) / e
        v = np.array([-ey, ex]) / e
        e_std = math.sqrt(max(float(u @ e_cov @ u), 0.0))
        phase_std = math.degrees(math.sqrt(max(float(v @ e_cov @ v), 0.0)) / e)
    else:
        e_std = math.sqrt(max(float(np.trace(e_cov)) / 2.0, 0.0))
        phase_std = 180.0
    shift = (float(p[2]), float(p[3])) if fit_axis else (0.0, 0.0)
    shift_cov = (float(p_cov[2, 2]), float(p_cov[2, 3]), float(p_cov[3, 3])) if fit_axis \
        else (0.0, 0.0, 0.0)
    tir = 2.0 * math.sqrt(max(e * e - float(np.trace(e_cov)), 0.0))
    return Runout(True, e, math.degrees(math.atan2(ey, ex)) % 360.0, tir, e_std,
                  min(phase_std, 180.0), 2.0 * e_std, shift, shift_cov, chi2 / dof, p_cov, n)


def span_deg(spindle_deg: np.ndarray) -> float:
    """How much of a revolution the angles (degrees) cover: 360 less the largest gap between
    them."""
    a = np.sort(np.mod(np.asarray(spindle_deg, np.float64).ravel(), 360.0))
    if len(a) < 2:
        return 0.0
    gaps = np.diff(np.concatenate([a, [a[0] + 360.0]]))
    return float(360.0 - gaps.max())


@dataclass(frozen=True)
class Harmonic:
    """One harmonic of the radius over the material's angle."""

    order: int
    amplitude_mm: float
    phase_deg: float
    amplitude_uncertainty_mm: float


@dataclass(frozen=True)
class Roundness:
    """The surface's form over a revolution.

    Attributes
    ----------
    ok : bool
        Whether the material's angles were covered well enough.
    radius_mm : float
        The least-squares reference circle's radius.
    ront_mm : float
        Peak-to-valley of the filtered profile about the reference circle (ISO 12181 RONt).
    ront_uncertainty_mm : float
        Its standard uncertainty (the noise left in the filtered profile).
    harmonics : list of Harmonic
        Orders 2 .. ``max_order`` (1 is the centre, 0 the radius).
    profile_deg, profile_mm : ndarray
        The filtered profile: the radius less the reference circle's at each material angle.
    dominant_order : int
        The order with the largest amplitude (0 when none stands above its noise).
    reason : str
        Why not, when ``ok`` is False.
    """

    ok: bool
    radius_mm: float = math.nan
    ront_mm: float = math.nan
    ront_uncertainty_mm: float = math.nan
    harmonics: list[Harmonic] = field(default_factory=list)
    profile_deg: np.ndarray = field(default_factory=lambda: np.empty(0), repr=False)
    profile_mm: np.ndarray = field(default_factory=lambda: np.empty(0), repr=False)
    dominant_order: int = 0
    reason: str = ""

    @property
    def odd_lobing(self) -> bool:
        """A dominant odd lobing (3, 5, 7 lobes): what a two-point measurement, and so a laser
        micrometer's peak-to-peak, cannot see."""
        return self.dominant_order % 2 == 1 and self.dominant_order >= 3


FORM_BINS = 1440
"""The material's angle is summed in this many bins a revolution (a quarter of a degree):
harmonic 50 loses 0.3 % of its amplitude to it."""


@lru_cache(maxsize=4)
def _harmonics_table(top: int) -> np.ndarray:
    """cos and sin of orders 1 .. ``top`` (in turn) at the bins' centres, (FORM_BINS, 2 top)."""
    grid = (np.arange(FORM_BINS) + 0.5) * (2.0 * math.pi / FORM_BINS)
    k = np.arange(1, top + 1)
    table = np.empty((FORM_BINS, 2 * top))
    table[:, 0::2] = np.cos(np.outer(grid, k))
    table[:, 1::2] = np.sin(np.outer(grid, k))
    table.flags.writeable = False
    return table


def form_of_frames(frames: Sequence[tuple[np.ndarray, np.ndarray]], upr: int = 50,
                   max_order: int = 15, noise_mm: float | None = None,
                   correlation: float | None = None, bins: int = 360,
                   min_coverage: float = 0.8, significance: float = 4.5) -> Roundness:
    """The form of a surface from many frames' points, each frame with a mean radius of its
    own (a fixed effect: its diameter's error, the part's diameter as it is turned, come out
    with it): ``roundness`` over frames.

    A frame's own mean takes from each harmonic its mean over the frame's arc; the normal
    equations keep that, so the harmonics come out whole (the price is less information on
    the low orders, whose mean over an arc is largest). Pooled as one set of points instead,
    frames 5 um off each bury lobes of a micrometre or two.

    Parameters
    ----------
    frames : sequence of (ndarray, ndarray)
        Each frame's points: material angles (rad) and radii about the surface's centre
        (mm), in their order along the frame's arc (the noise's correlation is read along it).
    correlation : float or None
        As ``roundness``; None: estimated from each frame's residuals along its arc.

    The other parameters are ``roundness``'s.
    """
    top = max(1, int(upr))
    m = 2 * top
    idx_l, y_l = [], []
    for beta, r in frames:
        beta = np.asarray(beta, np.float64).ravel()
        r = np.asarray(r, np.float64).ravel()
        keep = np.isfinite(beta) & np.isfinite(r)
        if keep.sum() >= 3:
            idx_l.append(np.minimum((np.mod(beta[keep], 2.0 * math.pi)
                                     * (FORM_BINS / (2.0 * math.pi))).astype(np.int64),
                                    FORM_BINS - 1))
            y_l.append(r[keep])
    nf = len(idx_l)
    n_pts = sum(len(y) for y in y_l)
    if n_pts < m + nf + 1:
        return Roundness(False, reason=f"{n_pts} points, need {m + nf + 1}")
    idx = np.concatenate(idx_l)
    ref = float(y_l[0].mean())  # radii kept about it: no large sums to cancel
    y = np.concatenate(y_l) - ref
    n_j = np.array([len(v) for v in y_l], np.float64)
    lab = np.repeat(np.arange(nf), n_j.astype(np.int64))
    y_mean = np.bincount(lab, weights=y, minlength=nf) / n_j
    yd = y - y_mean[lab]
    counts = np.bincount(idx, minlength=FORM_BINS).astype(np.float64)
    groups = (np.arange(FORM_BINS) * bins) // FORM_BINS
    coverage = float(np.mean(np.bincount(groups, weights=counts, minlength=bins) > 0))
    if coverage < min_coverage:
        return Roundness(False, reason=f"the points cover {coverage:.0%} of the material's "
                         f"angles, need {min_coverage:.0%}: more of a revolution")
    table = _harmonics_table(top)
    per_frame = np.bincount(lab * FORM_BINS + idx, minlength=nf * FORM_BINS)
    h_mean = (per_frame.reshape(nf, FORM_BINS).astype(np.float64) @ table) / n_j[:, None]
    gram = table.T @ (counts[:, None] * table) - (h_mean.T * n_j) @ h_mean
    rhs = table.T @ np.bincount(idx, weights=yd, minlength=FORM_BINS)
    eig = np.linalg.eigvalsh(gram)
    if not eig[0] > 1e-12 * eig[-1]:
        # Arcs that leave gaps in the material's angles leave the high orders open: their
        # amplitudes would be anything.
        return Roundness(False, reason=f"the points' material angles do not determine the "
                         f"form up to {top} undulations: more of a revolution")
    inv = np.linalg.inv(gram)
    coef = inv @ rhs
    resid = yd - (table @ coef)[idx] + (h_mean @ coef)[lab]
    dof = max(n_pts - nf - m, 1)
    sigma = float(noise_mm) if noise_mm is not None else math.sqrt(float(resid @ resid) / dof)
    if correlation is None:
        ends = np.cumsum(n_j.astype(np.int64))
        taus = [ck.correlation_factor(resid[e - len(v):e], 0.2)
                for e, v in zip(ends, y_l, strict=True)]
        correlation = float(np.average(taus, weights=n_j))
    coef_cov = sigma**2 * max(float(correlation), 1.0) * inv
    radius = ref + float(n_j @ (y_mean - h_mean @ coef)) / n_pts
    return _form(radius, coef, coef_cov, upr, max_order, bins, significance)


def roundness(material_deg: np.ndarray, radius_mm: np.ndarray, noise_mm: float | None = None,
              upr: int = 50, max_order: int = 15, bins: int = 360,
              min_coverage: float = 0.8, correlation: float | None = 1.0,
              significance: float = 4.5) -> Roundness:
    """The radius as a function of the material's angle, from points gathered over a
    revolution (each point's distance from the surface's centre at its frame, at its material
    angle), its least-squares reference circle, a Gaussian filter of ``upr`` undulations per
    revolution (ISO 12181's 50 % transmission at ``upr``), RONt and the harmonics. The points
    are taken as one set (``form_of_frames`` takes frames, each with its own mean radius).

    Parameters
    ----------
    material_deg, radius_mm : ndarray, shape (M,)
        Every point's material angle and radius.
    noise_mm : float, optional
        A point's radius noise (1 sigma); estimated from the points about the model when not
        given.
    upr : int
        The filter's cut-off, undulations per revolution (15 or 50).
    max_order : int
        Highest harmonic reported.
    bins : int
        The profile's samples per revolution (and the coverage's).
    min_coverage : float
        Share of the profile's bins that must hold points.
    correlation : float or None
        How many neighbouring points along a frame's arc share their noise (speckle: the
        variance inflation ``fit.correlation_factor``): the harmonics' uncertainties grow by
        its square root. None: estimated from the residuals about the fitted form, in the
        order the points are given.
    significance : float
        RONt's profile holds the harmonics that stand above this many of their standard
        uncertainties (0: all of them, the plain filtered profile), and the dominant order is
        the largest of them. Noise in fifty harmonics has a peak-to-valley of its own (7 um
        from 36 frames of a round simulated surface); at 4.5 a harmonic of noise alone
        passes once in 25,000 (Rayleigh), one of fifty once in 500.
    """
    return form_of_frames([(np.radians(np.asarray(material_deg, np.float64)),
                            np.asarray(radius_mm, np.float64))], upr, max_order, noise_mm,
                          correlation, bins, min_coverage, significance)


def _form(radius_mm: float, coef: np.ndarray, coef_cov: np.ndarray, upr: int, max_order: int,
          bins: int, significance: float) -> Roundness:
    """The filtered profile, RONt and the harmonics from the form's coefficients (cos and
    sine of orders 1 .. upr, in turn) and their covariance."""
    # ISO 16610-21's Gaussian filter for a closed profile: harmonic k passes with
    # exp(-pi (alpha k / upr)^2), alpha = sqrt(ln 2 / pi) (50 % at upr).
    alpha = math.sqrt(math.log(2.0) / math.pi)
    grid = np.radians((np.arange(bins) + 0.5) * 360.0 / bins)
    profile = np.zeros(bins)
    var_profile = 0.0
    harmonics = []
    for k in range(2, len(coef) // 2 + 1):
        c_, s_ = coef[2 * k - 2], coef[2 * k - 1]
        gain = math.exp(-math.pi * (alpha * k / upr) ** 2)
        cov2 = coef_cov[2 * k - 2:2 * k, 2 * k - 2:2 * k]
        amp, amp_std = math.hypot(c_, s_), math.sqrt(max(float(np.trace(cov2)) / 2.0, 0.0))
        # Every harmonic's noise counts in RONt's uncertainty, kept or left out (one left
        # out may hide form up to its threshold).
        var_profile += gain**2 * amp_std**2
        if amp > significance * amp_std:
            profile += gain * (c_ * np.cos(k * grid) + s_ * np.sin(k * grid))
        if k <= max_order:
            harmonics.append(Harmonic(k, amp, math.degrees(math.atan2(s_, c_)) % 360.0,
                                      amp_std))
    ront = float(profile.max() - profile.min())
    # The noise left in the filtered profile widens its peak-to-valley by about 2 sigma each
    # way at the extremes: taken as RONt's uncertainty.
    ront_std = 2.0 * math.sqrt(var_profile)
    significant = [h for h in harmonics
                   if h.amplitude_mm > significance * h.amplitude_uncertainty_mm]
    dominant = max(significant, key=lambda h: h.amplitude_mm).order if significant else 0
    return Roundness(True, float(radius_mm), ront, ront_std, harmonics, np.degrees(grid),
                     profile, dominant)


@dataclass(frozen=True)
class Concentricity:
    """Whether the frames' surface is concentric with the spindle axis, as far as the free
    fits of the last frames tell without the spindle's angle.

    Attributes
    ----------
    concentric : bool
        False when the free fits' centres stand off the axis, or move about it, beyond what
        their covariances allow.
    spread : float
        The frames' mean squared Mahalanobis distance of the free centre from the axis,
        halved (about 1 for a concentric surface: each is chi-square with 2 degrees of
        freedom).
    offset_sigmas : float
        The Mahalanobis distance of the frames' weighted mean centre from the axis: a surface
        off the axis at a frame rate locked to the spindle shows the same angle every frame.
    eccentricity_mm : float
        The surface's centre's RMS distance from the axis beyond the fits' own scatter: the
        eccentricity of a surface going round, or the offset of one seen at a locked angle.
    frames : int
        Free fits in the window.
    reason : str
        What it says, in words.
    """

    concentric: bool
    spread: float = 0.0
    offset_sigmas: float = 0.0
    eccentricity_mm: float = 0.0
    frames: int = 0
    reason: str = ""


@dataclass
class ConcentricityWatch:
    """The last ``window`` frames' free-fit centres against the (tracked) spindle axis.

    The ``axis`` method's accuracy rests on the surface being concentric with the spindle
    axis; raw stock, a second clamping or a bent part is not, and one frame cannot tell an
    offset along its arc's bisector from a change of diameter. Over a window it can: under
    concentricity each centre's squared Mahalanobis distance from the axis is chi-square with
    2 degrees of freedom, their mean about 2 and the weighted mean centre within a few sigmas
    of the axis. Either beyond its limit says the surface is not concentric: the weighted
    mean's at 1e-4 chance for a concentric surface (4.3 sigma); the spread's at 2, where a
    concentric surface in the simulator stays at 0.8-0.9 and 40 frames' chance would be 1e-8,
    room for covariances that are not quite right. It catches an eccentricity of 10 um on a
    turning surface and at a fixed angle; 5 um at a fixed angle along the arc's bisector it
    cannot tell from a change of diameter (that needs the spindle's angle: ``fit_runout``).
    A single frame whose own centre lies beyond ``frame_limit`` sigmas is off the axis too
    (the first frames of a part clamped off it, before the window has judged). A centre equal
    to one in the window is the same frame again and counts once. Pure: centres in, a verdict
    out.
    """

    window: int = 40
    min_frames: int = 10
    spread_limit: float = 2.0
    offset_limit: float = 4.3
    frame_limit: float = 4.3
    _d: list[np.ndarray] = field(default_factory=list)
    _w: list[np.ndarray] = field(default_factory=list)
    _var: list[float] = field(default_factory=list)
    _verdict: Concentricity | None = None

    def update(self, offset_mm: np.ndarray, cov_mm2: np.ndarray) -> float:
        """One frame's free-fit centre less the axis (section mm) and its covariance; returns
        that frame's Mahalanobis distance from the axis (NaN when it cannot be used): beyond
        ``frame_limit`` the frame itself is off the axis, whatever the window says yet."""
        d = np.asarray(offset_mm, np.float64).reshape(2)
        cov = np.asarray(cov_mm2, np.float64).reshape(2, 2)
        try:
            w = np.linalg.inv(cov)
        except np.linalg.LinAlgError:
            return math.nan
        if not (np.isfinite(d).all() and np.isfinite(w).all()):
            return math.nan
        self._d.append(d)
        self._w.append(w)
        self._var.append(float(np.trace(cov)))
        del self._d[:-self.window], self._w[:-self.window], self._var[:-self.window]
        self._verdict = None
        return math.sqrt(max(float(d @ w @ d), 0.0))

    def clear(self) -> None:
        """Forget the frames (a new part, a new calibration)."""
        self._d.clear()
        self._w.clear()
        self._var.clear()
        self._verdict = None

    def verdict(self) -> Concentricity:
        """What the window says (worked out once per new frame)."""
        if self._verdict is None:
            self._verdict = self._judge()
        return self._verdict

    def _judge(self) -> Concentricity:
        # The same centre twice is the same pixels again (a camera replaying its frames, a
        # stuck sensor): no new information, and counted twice it would shrink the mean's
        # uncertainty. Each frame is counted once; the window still forgets by arrival.
        seen = np.array(self._d).reshape(-1, 2)
        keep = np.sort(np.unique(seen, axis=0, return_index=True)[1])
        n = len(keep)
        if n < self.min_frames:
            return Concentricity(True, frames=n, reason=f"{n} free fits, judged from "
                                 f"{self.min_frames}")
        d, w = seen[keep], np.array(self._w)[keep]
        m2 = np.einsum("ni,nij,nj->n", d, w, d)
        spread = float(m2.mean()) / 2.0
        info = w.sum(axis=0)
        mean = np.linalg.solve(info, np.einsum("nij,nj->i", w, d))
        offset = math.sqrt(max(float(mean @ info @ mean), 0.0))
        var = np.array(self._var)[keep]
        ecc = math.sqrt(max(float(np.mean(np.sum(d * d, axis=1)) - np.mean(var)), 0.0))
        ecc = max(ecc, math.hypot(*mean))
        if spread > self.spread_limit or offset > self.offset_limit:
            return Concentricity(
                False, spread, offset, ecc, n,
                f"the surface is not concentric with the spindle axis: the free fits' "
                f"centres lie {ecc * 1000:.0f} um from it (spread {spread:.1f}, limit "
                f"{self.spread_limit:.1f}; mean {offset:.1f} sigma, limit "
                f"{self.offset_limit:.1f}): raw stock, a second clamping, a badly seated or "
                "bent part")
        return Concentricity(True, spread, offset, ecc, n, "concentric within the free "
                             "fits' uncertainty")
