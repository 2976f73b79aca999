"""Circle and ellipse fits of 2-D section points (mm), the paper's and better ones.

Every fit returns a result object that is falsy on failure (with a reason) rather than raising,
in the manner of scikit-image's ``measure.fit``:

- ``fit_kasa``: algebraic circle ``x^2 + y^2 + a x + b y + c = 0`` (paper Eq. 12-13, with the
  erratum ``d = 2 sqrt((a^2 + b^2)/4 - c)``);
- ``fit_hyper``: Al-Sharadqah and Chernov's "Hyper" algebraic fit, essentially unbiased, used
  to start the geometric fit;
- ``fit_geometric``: orthogonal-distance circle fit by Levenberg-Marquardt from ``fit_hyper``,
  with iterative rejection of outliers by a robust (MAD) scale;
- ``fit_paper``: the constrained centre fit of paper Eq. 19-23, as ``paper-notes.md`` item 7
  describes it;
- ``fit_ellipse``: conic ``x^2 + A xy + B y^2 + C x + D y + E = 0`` by least squares (paper
  Eq. 10-11); the minor axis is the diameter.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from service.measure import circle_kernels as ck
from service.measure.robust import median


@dataclass(frozen=True)
class CircleFit:
    """A fitted circle, or why there is none.

    Attributes
    ----------
    center : ndarray, shape (2,)
        Centre, mm (NaN on failure).
    radius : float
        Radius, mm (NaN on failure).
    rms : float
        RMS orthogonal residual of the inliers, mm.
    inliers : ndarray of bool, shape (N,)
        Points the fit kept.
    reason : str
        Empty on success; why the fit failed otherwise.
    radius_std : float
        Standard uncertainty of the radius, mm (``circle_radius_std``).
    """

    center: np.ndarray
    radius: float
    rms: float = math.nan
    inliers: np.ndarray = field(default_factory=lambda: np.empty(0, bool), repr=False)
    reason: str = ""
    radius_std: float = math.nan

    def __bool__(self) -> bool:
        return not self.reason and math.isfinite(self.radius) and self.radius > 0

    @property
    def diameter(self) -> float:
        """Diameter, mm."""
        return 2.0 * self.radius

    @classmethod
    def failure(cls, reason: str, n: int = 0) -> CircleFit:
        """A failed fit."""
        return cls(np.full(2, np.nan), math.nan, math.nan, np.zeros(n, bool), reason)


@dataclass(frozen=True)
class EllipseFit:
    """A fitted ellipse (conic), or why there is none.

    Attributes
    ----------
    coeffs : ndarray, shape (5,)
        ``(A, B, C, D, E)`` of ``x^2 + A xy + B y^2 + C x + D y + E = 0`` in the fit's centred
        coordinates.
    center : ndarray, shape (2,)
        Ellipse centre in the input coordinates, mm.
    semi_axes : tuple of float
        (semi-major, semi-minor), mm.
    rms : float
        RMS Sampson (first-order geometric) distance of the points, mm.
    reason : str
        Empty on success.
    minor_std : float
        Standard uncertainty of the semi-minor axis, mm.
    """

    coeffs: np.ndarray
    center: np.ndarray
    semi_axes: tuple[float, float]
    rms: float = math.nan
    reason: str = ""
    minor_std: float = math.nan

    def __bool__(self) -> bool:
        return not self.reason and all(math.isfinite(s) and s > 0 for s in self.semi_axes)

    @property
    def minor_diameter(self) -> float:
        """Length of the minor axis, mm: the shaft diameter."""
        return 2.0 * self.semi_axes[1]


def _check_points(points: np.ndarray, need: int) -> str:
    pts = np.asarray(points)
    if pts.ndim != 2 or pts.shape[1] != 2:
        return f"points must have shape (N, 2), got {pts.shape}"
    if pts.shape[0] < need:
        return f"{pts.shape[0]} points, need at least {need}"
    if not np.isfinite(pts).all():
        return "points contain NaN or infinity"
    return ""


def circle_rms(points: np.ndarray, center: np.ndarray, radius: float) -> float:
    """RMS orthogonal distance of points (mm) to a circle, mm."""
    pts = np.ascontiguousarray(points, np.float64)
    if len(pts) == 0:
        return math.nan
    return ck.circle_rms(pts, float(center[0]), float(center[1]), float(radius))


def correlation_factor(residuals: np.ndarray, max_lag_fraction: float = 0.2) -> float:
    """Variance inflation for residuals that are correlated along the stripe.

    Neighbouring stripe centres share speckle grains and the extractor's smoothing, so N points
    carry the information of about N / tau independent ones, with ``tau = 1 + 2 sum rho_k``
    the integrated autocorrelation of the residuals in arc order (summed while rho_k stays
    above 0.05, as in Geyer's initial positive sequence).

    Parameters
    ----------
    residuals : ndarray, shape (N,)
        Residuals in the order of the points along the arc, mm.
    max_lag_fraction : float
        Longest lag considered, as a fraction of N.

    Returns
    -------
    float
        ``tau >= 1``.
    """
    return float(ck.correlation_factor(np.asarray(residuals, np.float64), max_lag_fraction))


def circle_covariance(points: np.ndarray, center: np.ndarray, radius: float,
                      center_prior_sigma: float | None = None,
                      weights: np.ndarray | None = None,
                      inliers: np.ndarray | None = None,
                      clip: float | None = None) -> np.ndarray:
    """Covariance of (cx, cy, r) of a circle fit, mm^2, from its Jacobian and residuals.

    ``s^2 (J^T W J)^-1`` with ``s^2`` the weighted residual variance, inflated by
    ``correlation_factor`` for residuals correlated along the arc; with a centre prior of
    standard deviation ``center_prior_sigma`` (mm) its information is added to the centre's.

    With ``inliers`` the Jacobian and ``s^2`` are the kept points' (the points a fit kept of
    ``points``). With ``clip`` too (the weighted residual beyond which the fit set points
    aside, mm) the points set aside just past it, within twice it, count in ``s^2`` at
    ``clip``: the winsorized variance of a trimmed mean. They are the tails of the stripe's
    own scatter, cut one frame more on one side, another on the other, which moves the fit
    by more than the kept points show; points farther out are something else (a glint, a
    drop's rim) and do not count. ``fit_axis_prior`` counts them: with the axis exact, the
    z-scores' standard deviation went from 1.20 to 1.07 on the default rig (120 frames,
    three diameters) and from 1.21 to 1.07 at a sheet sigma of 0.15 mm. The free fit does
    not: on a 130-degree arc its plain uncertainty was honest (1.05) and the winsorized one
    not (0.84).
    """
    pts = np.asarray(points, np.float64)
    w = np.ones(len(pts)) if weights is None else np.asarray(weights, np.float64)
    use = np.ones(len(pts), bool) if inliers is None else np.asarray(inliers, bool)
    n_free = 3 if center_prior_sigma is None else 1
    info = ck.circle_information(np.ascontiguousarray(pts[:, 0]), np.ascontiguousarray(pts[:, 1]),
                                 float(center[0]), float(center[1]), float(radius), w, n_free,
                                 use, math.inf if clip is None else float(clip))
    if center_prior_sigma is not None:
        info[0, 0] += 1.0 / center_prior_sigma**2
        info[1, 1] += 1.0 / center_prior_sigma**2
    return ck.inverse3(info)


def rejection_clip(points: np.ndarray, center: np.ndarray, radius: float,
                   weights: np.ndarray, inliers: np.ndarray, reject_k: float,
                   floor_mm: float) -> float:
    """The weighted residual beyond which ``fit_axis_prior``'s rejection rounds set points
    aside, mm: ``reject_k`` robust standard deviations (MAD) of the inliers' residuals about
    their median, at least ``floor_mm``."""
    pts = np.asarray(points, np.float64)
    return float(ck.rejection_clip(np.ascontiguousarray(pts[:, 0]),
                                   np.ascontiguousarray(pts[:, 1]), float(center[0]),
                                   float(center[1]), float(radius),
                                   np.sqrt(np.asarray(weights, np.float64)),
                                   np.asarray(inliers, bool), float(reject_k), float(floor_mm)))


def circle_radius_std(points: np.ndarray, center: np.ndarray, radius: float,
                      weights: np.ndarray | None = None,
                      inliers: np.ndarray | None = None) -> float:
    """Standard uncertainty of a free circle fit's radius, mm (``circle_covariance``)."""
    cov = circle_covariance(points, center, radius, weights=weights, inliers=inliers)
    return float(math.sqrt(max(cov[2, 2], 0.0))) if np.isfinite(cov[2, 2]) else math.inf


def _with_std(fit: CircleFit, points: np.ndarray, weights: np.ndarray | None = None
              ) -> CircleFit:
    if not fit:
        return fit
    keep = fit.inliers if fit.inliers.size == len(points) else np.ones(len(points), bool)
    return replace(fit, radius_std=circle_radius_std(points, fit.center, fit.radius, weights,
                                                     keep))


def point_weights(strength: np.ndarray | None, n: int) -> np.ndarray:
    """Relative weights of stripe points from their strength (curvature across the stripe).

    A Steger centre's noise scales as noise / curvature, so a weak point (where the stripe
    fades) gets ``(strength / median)^2``; points at or above the median get 1, since speckle,
    the larger error, is multiplicative and does not shrink with brightness.
    """
    if strength is None:
        return np.ones(n)
    s = np.asarray(strength, np.float64)
    med = median(s) if s.size else 0.0
    if not med > 0:
        return np.ones(n)
    return np.clip((s / med) ** 2, 1e-3, 1.0)


def arc_variance(points: np.ndarray, center: np.ndarray, inliers: np.ndarray,
                 residuals: np.ndarray, max_ratio: float = 16.0) -> np.ndarray:
    """Relative variance of each point's residual, a smooth function of its place on the arc.

    Along the stripe the points' scatter is not the same: where the camera sees the shaft
    obliquely the stripe is wider (speckle moves its centre by the width squared times the
    speckle's slope) and each pixel spans more of the section; at 21.7 mm the residuals
    scattered 4 um in the middle of the arc and 10 um at its ends. A quadratic in the angle
    is fitted by least squares to the logarithm of the inliers' squared residuals (a
    feasible generalised least squares: the profile is the data's, not a model of the rig),
    so that the points can be weighted by the inverse.

    Parameters
    ----------
    points : ndarray, shape (N, 2)
        Section points, mm.
    center : ndarray, shape (2,)
        The fitted centre, mm.
    inliers : ndarray of bool, shape (N,)
        The points the fit kept (the profile is fitted to them).
    residuals : ndarray, shape (N,)
        The points' residuals about the fit (weighted as the fit weighs them), mm.
    max_ratio : float
        The profile stays within ``1 / max_ratio`` and ``max_ratio`` of its median.

    Returns
    -------
    ndarray, shape (N,)
        Relative variances, median 1 over the inliers; all ones when there are too few
        inliers to say (fewer than thirty: ten per coefficient).
    """
    use = np.asarray(inliers, bool)
    if use.sum() < 30:
        return np.ones(len(points))
    pts = np.asarray(points, np.float64)
    return ck.arc_variance(np.ascontiguousarray(pts[:, 0]), np.ascontiguousarray(pts[:, 1]),
                           float(center[0]), float(center[1]), use,
                           np.asarray(residuals, np.float64), float(max_ratio))


def fit_kasa(points: np.ndarray) -> CircleFit:
    """Algebraic (Kasa) circle fit, paper Eq. 12-13 with the erratum.

    Minimises ``sum (x^2 + y^2 + a x + b y + c)^2``. Fast and closed-form, but its radius is
    biased low on short, noisy arcs.

    Parameters
    ----------
    points : ndarray, shape (N, 2)
        Points, mm; N >= 3.

    Returns
    -------
    CircleFit
    """
    reason = _check_points(points, 3)
    if reason:
        return CircleFit.failure(reason, len(np.atleast_2d(points)))
    pts = np.asarray(points, np.float64)
    mean = pts.mean(axis=0)
    x, y = (pts - mean).T  # the fit is translation invariant; centring keeps it well posed
    design = np.column_stack([x, y, np.ones_like(x)])
    (a, b, c), _, rank, _ = np.linalg.lstsq(design, -(x * x + y * y), rcond=None)
    r2 = (a * a + b * b) / 4.0 - c
    if rank < 3:
        return CircleFit.failure("Kasa fit is degenerate (points on a line)", len(pts))
    if not (np.isfinite(r2) and r2 > 0):
        return CircleFit.failure("Kasa fit is degenerate (points on a line?)", len(pts))
    center = mean + np.array([-a / 2.0, -b / 2.0])
    radius = math.sqrt(r2)
    return _with_std(CircleFit(center, radius, circle_rms(pts, center, radius),
                               np.ones(len(pts), bool)), pts)


def fit_hyper(points: np.ndarray, uncertainty: bool = True) -> CircleFit:
    """Hyper algebraic circle fit (Al-Sharadqah & Chernov 2009), SVD form.

    Its radius has no essential bias, so it is a good start for the geometric fit.

    Parameters
    ----------
    points : ndarray, shape (N, 2)
        Points, mm; N >= 3.
    uncertainty : bool
        Also compute ``radius_std`` (False leaves it NaN: a preliminary circle needs none).

    Returns
    -------
    CircleFit
    """
    reason = _check_points(points, 3)
    if reason:
        return CircleFit.failure(reason, len(np.atleast_2d(points)))
    pts = np.asarray(points, np.float64)
    mean = pts.mean(axis=0)
    x, y = (pts - mean).T
    z = x * x + y * y
    m = np.column_stack([z, x, y, np.ones_like(x)])
    _, s, vt = np.linalg.svd(m, full_matrices=False)
    v = vt.T
    if s[-1] / s[0] < 1e-12:  # points exactly on a circle
        coef = v[:, -1]
    else:
        zm, xm, ym = z.mean(), x.mean(), y.mean()
        hyper_n = np.array([
            [8.0 * zm, 4.0 * xm, 4.0 * ym, 2.0],
            [4.0 * xm, 1.0, 0.0, 0.0],
            [4.0 * ym, 0.0, 1.0, 0.0],
            [2.0, 0.0, 0.0, 0.0],
        ])  # Hyper's constraint matrix N
        n_inv = np.linalg.inv(hyper_n)
        w = v @ np.diag(s) @ v.T
        evals, evecs = np.linalg.eig(w @ n_inv @ w)
        evals = evals.real
        order = np.argsort(evals)
        pos = [i for i in order if evals[i] > 0]
        if not pos:
            return CircleFit.failure("Hyper fit found no positive eigenvalue", len(pts))
        coef = np.linalg.solve(w, evecs[:, pos[0]].real)
    if abs(coef[0]) < 1e-300:
        return CircleFit.failure("Hyper fit is degenerate (points on a line?)", len(pts))
    center = mean - coef[1:3] / (2.0 * coef[0])
    r2 = (coef[1] ** 2 + coef[2] ** 2 - 4.0 * coef[0] * coef[3]) / (4.0 * coef[0] ** 2)
    if not (np.isfinite(r2) and r2 > 0):
        return CircleFit.failure("Hyper fit gave no real circle", len(pts))
    radius = math.sqrt(r2)
    fit = CircleFit(center, radius, circle_rms(pts, center, radius), np.ones(len(pts), bool))
    return _with_std(fit, pts) if uncertainty else fit


def fit_geometric(
    points: np.ndarray, reject_k: float = 3.5, max_rounds: int = 6, floor_mm: float = 1e-4,
    weights: np.ndarray | None = None, start: CircleFit | None = None,
    uncertainty: bool = True,
) -> CircleFit:
    """Orthogonal-distance circle fit with robust outlier rejection.

    Minimises ``sum (|p_i - c| - r)^2`` by Levenberg-Marquardt, started from ``fit_hyper``.
    After each fit the points farther than ``reject_k`` robust standard deviations (MAD of the
    inliers' residuals) are set aside and the fit repeats on the rest, until the inlier set
    stops changing.

    Parameters
    ----------
    points : ndarray, shape (N, 2)
        Points, mm; N >= 3.
    reject_k : float
        Rejection threshold in robust standard deviations.
    max_rounds : int
        Most fit-and-reject rounds.
    floor_mm : float
        Least rejection distance, mm, so that near-perfect data keeps its points.
    weights : ndarray, shape (N,), optional
        Relative weights (``point_weights``); residuals are judged scaled by sqrt(weight).
    start : CircleFit, optional
        A fit of nearly the same points to start from (its centre, radius and inliers)
        instead of ``fit_hyper``.
    uncertainty : bool
        Compute ``radius_std`` (NaN without it): a fit that only starts another needs none.

    Returns
    -------
    CircleFit
        ``inliers`` marks the points kept.
    """
    reason = _check_points(points, 3)
    if reason:
        return CircleFit.failure(reason, len(np.atleast_2d(points)))
    pts = np.asarray(points, np.float64)
    w = np.ones(len(pts)) if weights is None else np.asarray(weights, np.float64)
    sw = np.sqrt(w)
    inliers = np.ones(len(pts), bool)
    fit = start if start and start.inliers.size == len(pts) \
        else fit_hyper(pts, uncertainty=False)
    if not fit:
        return fit
    inliers = start.inliers if fit is start else inliers
    cx, cy, radius, inliers, status = ck.robust_rounds(
        np.ascontiguousarray(pts[:, 0]), np.ascontiguousarray(pts[:, 1]), sw,
        float(fit.center[0]), float(fit.center[1]), float(fit.radius), inliers, False,
        0.0, 0.0, 1.0, reject_k, max_rounds, floor_mm)
    if status == 1:
        return CircleFit.failure("outlier rejection left fewer than 3 points", len(pts))
    if status == 2:
        return CircleFit.failure("geometric fit did not converge", len(pts))
    center = np.array([cx, cy])
    fit = CircleFit(center, radius, circle_rms(pts[inliers], center, radius), inliers)
    return _with_std(fit, pts, w) if uncertainty else fit


def order_along_arc(points: np.ndarray, center: np.ndarray) -> np.ndarray:
    """Indices that sort points by angle around ``center``, starting after the largest gap."""
    pts = np.asarray(points, np.float64)
    return ck.order_along_arc(np.ascontiguousarray(pts[:, 0]), np.ascontiguousarray(pts[:, 1]),
                              float(center[0]), float(center[1]))


def arc_span_deg(points: np.ndarray, center: np.ndarray) -> float:
    """Angular span of points around a centre, degrees: 360 minus the largest empty gap."""
    if len(points) < 2 or not np.isfinite(center).all():
        return 0.0
    pts = np.asarray(points, np.float64)
    return math.degrees(ck.arc_span(np.ascontiguousarray(pts[:, 0]),
                                    np.ascontiguousarray(pts[:, 1]),
                                    float(center[0]), float(center[1])))


def _chord_crossings(a: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Intersection E of chords AC and BD, row by row (NaN where they are parallel)."""
    u, v = c - a, d - b
    cross = u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]
    w = b - a
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (w[:, 0] * v[:, 1] - w[:, 1] * v[:, 0]) / cross
    return a + s[:, None] * u


def fit_paper(points: np.ndarray) -> CircleFit:
    """The paper's constrained centre fit (Eq. 19-23), as ``paper-notes.md`` item 7 fixes it.

    Points are put in arc order around the Kasa centre; with ``m = N // 4`` the quadruples are
    ``A, B, C, D = p[i], p[i+m], p[i+2m], p[i+3m]`` for every ``i + 3m < N``, so chords AC and
    BD cross inside the circle at E. For unknowns ``(x0, y0, r)`` the residuals are the power of
    E, ``|AE||CE| - (r^2 - |OE|^2)`` and ``|BE||DE| - (r^2 - |OE|^2)``, and the perpendicular
    bisectors, ``(O - mid(A, C)) . (A - C)`` and ``(O - mid(B, D)) . (B - D)``; their sum of
    squares is minimised by Levenberg-Marquardt from the Kasa fit. The diameter is
    ``2 mean |p_i - O|`` (Eq. 23), so the returned radius is that mean distance.

    Parameters
    ----------
    points : ndarray, shape (N, 2)
        Points, mm; N >= 8.

    Returns
    -------
    CircleFit
    """
    reason = _check_points(points, 8)
    if reason:
        return CircleFit.failure(reason, len(np.atleast_2d(points)))
    pts = np.asarray(points, np.float64)
    start = fit_kasa(pts)
    if not start:
        return start
    p = pts[order_along_arc(pts, start.center)]
    n = len(p)
    m = n // 4
    idx = np.arange(0, n - 3 * m)
    a, b, c, d = p[idx], p[idx + m], p[idx + 2 * m], p[idx + 3 * m]
    e = _chord_crossings(a, b, c, d)
    good = np.isfinite(e).all(axis=1)
    a, b, c, d, e = a[good], b[good], c[good], d[good], e[good]
    if len(e) == 0:
        return CircleFit.failure("no crossing chord pairs (points on a line?)", n)
    ae_ce = np.linalg.norm(a - e, axis=1) * np.linalg.norm(c - e, axis=1)
    be_de = np.linalg.norm(b - e, axis=1) * np.linalg.norm(d - e, axis=1)
    mid_ac, dir_ac = 0.5 * (a + c), a - c
    mid_bd, dir_bd = 0.5 * (b + d), b - d

    def residuals(q: np.ndarray) -> np.ndarray:
        o, r = q[:2], q[2]
        oe2 = np.sum((o - e) ** 2, axis=1)
        return np.concatenate([
            ae_ce - (r * r - oe2),
            be_de - (r * r - oe2),
            np.sum((o - mid_ac) * dir_ac, axis=1),
            np.sum((o - mid_bd) * dir_bd, axis=1),
        ])

    # Imported here: scipy.optimize costs 0.4 s at every start of a process that measures,
    # and only the paper's method uses it.
    from scipy.optimize import least_squares

    x0 = np.array([start.center[0], start.center[1], start.radius])
    sol = least_squares(residuals, x0, method="lm", xtol=1e-12, ftol=1e-12)
    if not sol.success or not np.isfinite(sol.x).all():
        return CircleFit.failure("constrained centre fit did not converge", n)
    center = sol.x[:2]
    radius = float(np.mean(np.hypot(pts[:, 0] - center[0], pts[:, 1] - center[1])))
    if not radius > 0 or abs(radius - start.radius) > start.radius:
        return CircleFit.failure("constrained centre fit diverged from its start", n)
    return _with_std(CircleFit(center, radius, circle_rms(pts, center, radius),
                               np.ones(n, bool)), pts)


def fit_axis_prior(points: np.ndarray, center_prior: np.ndarray, center_sigma: float,
                   reject_k: float = 3.5, max_rounds: int = 6,
                   floor_mm: float = 1e-4, weights: np.ndarray | None = None,
                   start: CircleFit | None = None, uncertainty: bool = True) -> CircleFit:
    """Circle with a Gaussian prior on its centre, by maximum a posteriori.

    A surface turned on the lathe is concentric with the spindle axis, so the section centre
    is known beforehand to within ``center_sigma``. The fit minimises
    ``sum ((|p_i - c| - r) / s)^2 + |c - c0|^2 / center_sigma^2`` over ``(c, r)``, with ``s``
    the points' noise (estimated robustly from the residuals about the prior centre and
    inflated for correlation along the arc), by Levenberg-Marquardt, rejecting outliers by
    a MAD scale as ``fit_geometric`` does. On a short arc, where a free fit trades centre
    against radius, the prior pins the centre and leaves the radius to the data.

    Parameters
    ----------
    points : ndarray, shape (N, 2)
        Section points, mm; N >= 3.
    center_prior : ndarray, shape (2,)
        Prior centre ``c0`` (the spindle axis in section coordinates), mm.
    center_sigma : float
        Standard deviation of the prior centre, mm (> 0).
    reject_k, max_rounds, floor_mm, weights
        Outlier rejection and point weights, as in ``fit_geometric``.
    start : CircleFit, optional
        A fit of nearly the same points to start from (its centre, radius and inliers).
    uncertainty : bool
        Compute ``radius_std`` (NaN without it): a fit that only starts another needs none.

    Returns
    -------
    CircleFit
        With ``radius_std`` from the posterior covariance.
    """
    reason = _check_points(points, 3)
    if reason:
        return CircleFit.failure(reason, len(np.atleast_2d(points)))
    c0 = np.asarray(center_prior, np.float64)
    if not (np.isfinite(c0).all() and center_sigma > 0):
        return CircleFit.failure("centre prior must be finite with a positive sigma",
                                 len(points))
    pts = np.asarray(points, np.float64)
    w = np.ones(len(pts)) if weights is None else np.asarray(weights, np.float64)
    sw_all = np.sqrt(w)
    if start and start.inliers.size == len(pts):
        inliers, center, radius = start.inliers.copy(), start.center.copy(), start.radius
    else:
        inliers, center = np.ones(len(pts), bool), c0.copy()
        radius = float(np.hypot(pts[:, 0] - c0[0], pts[:, 1] - c0[1]) @ w / w.sum())
    cx, cy, radius, inliers, status = ck.robust_rounds(
        np.ascontiguousarray(pts[:, 0]), np.ascontiguousarray(pts[:, 1]), sw_all,
        float(center[0]), float(center[1]), float(radius), inliers, True, float(c0[0]),
        float(c0[1]), float(center_sigma), reject_k, max_rounds, floor_mm)
    if status == 1:
        return CircleFit.failure("outlier rejection left fewer than 3 points", len(pts))
    if status == 2:
        return CircleFit.failure("axis-prior fit did not converge", len(pts))
    center = np.array([cx, cy])
    use = pts[inliers]
    fit = CircleFit(center, radius, circle_rms(use, center, radius), inliers)
    return with_radius_std(fit, pts, w, center_sigma, reject_k, floor_mm) if uncertainty \
        else fit


def with_radius_std(fit: CircleFit, points: np.ndarray, weights: np.ndarray,
                    center_sigma: float | None = None, reject_k: float = 3.5,
                    floor_mm: float = 1e-4) -> CircleFit:
    """``fit`` (of ``points`` with ``weights``, made with ``uncertainty=False``) with the
    ``radius_std`` its fit would have given: ``fit_axis_prior``'s with ``center_sigma`` (and
    the same ``reject_k``, ``floor_mm``), else ``fit_geometric``'s."""
    if not fit:
        return fit
    pts = np.asarray(points, np.float64)
    w = np.asarray(weights, np.float64)
    if center_sigma is None:
        return _with_std(fit, pts, w)
    clip = rejection_clip(pts, fit.center, fit.radius, w, fit.inliers, reject_k, floor_mm)
    cov = circle_covariance(pts, fit.center, fit.radius, center_prior_sigma=center_sigma,
                            weights=w, inliers=fit.inliers, clip=clip)
    std = float(math.sqrt(max(cov[2, 2], 0.0))) if np.isfinite(cov[2, 2]) else math.inf
    return replace(fit, radius_std=std)


def conic_semi_axes(coeffs: np.ndarray) -> tuple[np.ndarray, float, float] | None:
    """Centre and semi-axes (major, minor) of ``x^2 + A xy + B y^2 + C x + D y + E = 0``.

    The minor semi-axis squared is ``2 N / ((4B - A^2)(1 + B + s))`` with
    ``N = D^2 + B C^2 - A C D + (A^2 - 4B) E`` and ``s = sqrt(A^2 + (1 - B)^2)``: paper Eq. 11
    (signs rearranged); the major uses ``1 + B - s``. None when the conic is not a real ellipse.
    """
    A, B, C, D, E = (float(v) for v in coeffs)
    disc = 4.0 * B - A * A
    if disc <= 0:
        return None
    num = D * D + B * C * C - A * C * D - disc * E
    s = math.hypot(A, 1.0 - B)
    if num <= 0 or 1.0 + B - s <= 0:
        return None
    minor2 = 2.0 * num / (disc * (1.0 + B + s))
    major2 = 2.0 * num / (disc * (1.0 + B - s))
    center = np.array([(A * D - 2.0 * B * C) / disc, (A * C - 2.0 * D) / disc])
    return center, math.sqrt(major2), math.sqrt(minor2)


def fit_ellipse(points: np.ndarray) -> EllipseFit:
    """Least-squares conic with unit ``x^2`` coefficient (paper Eq. 10-11, Appendix B).

    Parameters
    ----------
    points : ndarray, shape (N, 2)
        Points in light-plane coordinates, mm; N >= 5. They are centred on their mean first
        (the algebraic fit is not translation invariant; centring keeps it well conditioned).

    Returns
    -------
    EllipseFit
        ``minor_diameter`` is the shaft diameter.
    """
    reason = _check_points(points, 5)
    nan2 = np.full(2, np.nan)
    if reason:
        return EllipseFit(np.full(5, np.nan), nan2, (math.nan, math.nan), reason=reason)
    pts = np.asarray(points, np.float64)
    mean = pts.mean(axis=0)
    x, y = (pts - mean).T
    design = np.column_stack([x * y, y * y, x, y, np.ones_like(x)])
    coeffs, *_ = np.linalg.lstsq(design, -(x * x), rcond=None)
    axes = conic_semi_axes(coeffs)
    if axes is None:
        return EllipseFit(coeffs, nan2, (math.nan, math.nan),
                          reason="conic fit is not an ellipse (arc too short or too noisy)")
    center, major, minor = axes
    A, B, C, D, _ = coeffs
    f = x * x + design @ coeffs
    grad = np.hypot(2 * x + A * y + C, A * x + 2 * B * y + D)
    sampson = f / np.maximum(grad, 1e-300)
    rms = float(np.sqrt(np.mean(sampson**2)))
    return EllipseFit(coeffs, center + mean, (major, minor), rms,
                      minor_std=_minor_std(design, f, coeffs, sampson, x, y))


def _minor_std(design: np.ndarray, f: np.ndarray, coeffs: np.ndarray, sampson: np.ndarray,
               x: np.ndarray, y: np.ndarray) -> float:
    """Standard uncertainty of the semi-minor axis: the coefficients' least-squares covariance
    (inflated for correlation along the arc) propagated by a numerical gradient."""
    dof = max(len(f) - 5, 1)
    order = np.argsort(np.arctan2(y - y.mean(), x - x.mean()))
    s2 = float(f @ f) / dof * correlation_factor(sampson[order])
    try:
        cov = s2 * np.linalg.inv(design.T @ design)
    except np.linalg.LinAlgError:
        return math.inf
    grad = np.zeros(5)
    for i in range(5):
        h = 1e-6 * max(abs(coeffs[i]), 1e-3)
        up, dn = coeffs.copy(), coeffs.copy()
        up[i] += h
        dn[i] -= h
        a_up, a_dn = conic_semi_axes(up), conic_semi_axes(dn)
        if a_up is None or a_dn is None:
            return math.inf
        grad[i] = (a_up[2] - a_dn[2]) / (2 * h)
    return float(math.sqrt(max(grad @ cov @ grad, 0.0)))
