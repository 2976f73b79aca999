"""A secondary reflection beside the stripe: find it in the stripe's own profiles and take out
the pull it leaves in the centres.

A reflection (a fainter, blurred copy of the stripe moved by a fixed image offset ``d``) close
to the stripe merges with it under the derivative filters and pulls every centre toward it by
up to tenths of a pixel: tens of micrometres of radius. Across the stripe at a centre with
unit normal ``n`` the reflection stands ``d . n`` px away, so one offset explains every
centre's profile. The profiles are sampled along the normals, averaged within a few bins of
normal direction (the speckle averages out; the reflection's offset across the stripe is
nearly the same within a bin) and fitted by::

    p_k(s) = B_k + C_k s + A_k [ G(s - u_k; w_k) + gain G(s - u_k - d . n_k; sqrt(w_k^2 + b^2)) ]

with ``G(s; w) = exp(-s^2 / 2 w^2)``: per bin a background ``B_k`` with a slope ``C_k`` (stray
light, a lit edge the stripe crosses), height ``A_k``, width ``w_k`` and the stripe's true
centre ``u_k`` relative to the measured centres (px along the normal); shared by all bins the
reflection's offset ``d`` (px), relative height ``gain`` and extra blur ``b`` (px). ``u_k`` is
the pull to undo: each centre moves by ``u`` interpolated at its normal's direction.
Everything is estimated from the image: nothing about the laser or the reflection is assumed
beyond its being a shifted, blurred copy.

Pure functions, no I/O; a fit that does not hold returns a falsy ``Reflection`` with the
reason.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from service.measure.band import full_scale
from service.measure.robust import median

__all__ = ["Reflection", "ReflectionParams", "cross_profiles", "fit_reflection"]


@dataclass(frozen=True)
class ReflectionParams:
    """Settings of the reflection model.

    Attributes
    ----------
    bins : int
        Bins of normal direction whose mean profiles are fitted.
    reach_px : float
        Half-length of each profile along the normal, px: a reflection farther off stands
        apart as a line of its own (and the section's consensus drops it).
    step_px : float
        Sampling step along the normal, px.
    min_per_bin : int
        Fewest centres a bin must average.
    min_explained : float
        Least share of the single line's misfit to the profiles that the reflection must
        explain for a stripe that is not lopsided (a clean stripe's profile is not quite a
        Gaussian: a reflection explains 4-59 % of that misfit over the rig range; 65-96 %
        when there is one of 0.08 of the stripe's light, 40-90 % at 0.05).
    min_explained_asymmetry : float
        ... or, for a lopsided stripe, least share of the single line's odd misfit (one side
        against the other) that the reflection must explain: below both the lopsidedness is
        something else and is not corrected.
    screen_margin : float
        A stripe that is not lopsided is cleared without the reflection's fit when the linear
        screen (``_starts``: reflections on a grid of offsets beside the single line's fit,
        heights solved linearly) explains less than ``min_explained`` less this margin of the
        misfit. The screen reads within 0.02 of the fit where there is a reflection (gains
        0.05-0.35, 2-6 px off) and above it where there is none (up to 0.62 against 0.46 at
        a 0.15 mm sheet): it clears 0.09-0.37 at the default sheet.
    screen_max_misfit : float
        ... and only when the single line leaves at most this share of the profiles'
        variance unexplained: a reflection as bright as the stripe drags the single line
        between the two, where the screen's linearisation no longer holds (screen 0.23-0.55
        where the fit finds 0.72-1.0), and leaves 0.19-5 % (a clean stripe: 0.01-0.09 %
        over the rig range).
    max_clipped : float
        Largest share of centres whose core is clipped at the sensor's full scale. A stripe
        clipped along its whole length is flat-topped, not the model's Gaussian line (an
        unspeckled line at 3.6 times full scale: its centres moved a quarter pixel past the
        truth); where speckle leaves some centres below full scale the mean profiles stay
        rounded (speckle of contrast 0.25, three times full scale, 90 % of the centres
        clipped: 0.30 px of pull taken to 0.03).
    max_gain : float
        A "reflection" brighter than this share of the stripe may be the stripe: refused.
    max_shift_px : float
        A larger modelled pull is not trusted.
    starts : int
        The fit of a lopsided stripe starts from this many of the best reflections on a grid
        of offsets (a stripe that is not lopsided, from the best one).
    """

    bins: int = 6
    reach_px: float = 9.0
    step_px: float = 0.5
    min_per_bin: int = 8
    min_explained: float = 0.7
    min_explained_asymmetry: float = 0.75
    screen_margin: float = 0.1
    screen_max_misfit: float = 0.0015
    max_clipped: float = 0.95
    max_gain: float = 0.9
    max_shift_px: float = 1.0
    starts: int = 3


@dataclass(frozen=True)
class Reflection:
    """A fitted reflection, or (falsy) why none could be fitted.

    Attributes
    ----------
    offset_px : tuple of float
        The reflection's image offset from the stripe (dx, dy), px.
    gain : float
        Its peak height relative to the stripe's.
    blur_px : float
        Its extra Gaussian blur, px.
    shift_px : ndarray, shape (N,)
        How far each centre must move along its given normal to undo the pull, px.
    explained : float
        Share of the single line's misfit to the profiles that the reflection explains (0-1).
    explained_asymmetry : float
        ... and of the odd part of that misfit (one side of the stripe against the other).
    reason : str
        Why there is no fit, when there is none.
    """

    offset_px: tuple[float, float] = (0.0, 0.0)
    gain: float = 0.0
    blur_px: float = 0.0
    shift_px: np.ndarray = field(default_factory=lambda: np.zeros(0))
    explained: float = 0.0
    explained_asymmetry: float = 0.0
    reason: str = ""

    def __bool__(self) -> bool:
        return not self.reason

    def describe(self) -> str:
        """One line for a measurement's note."""
        dx, dy = self.offset_px
        return (f"a reflection at ({dx:+.1f}, {dy:+.1f}) px, {self.gain:.2f} of the stripe's "
                f"height, was modelled and its pull taken out (up to "
                f"{np.max(np.abs(self.shift_px)) if self.shift_px.size else 0.0:.2f} px)")


def cross_profiles(image: np.ndarray, xy: np.ndarray, normal: np.ndarray,
                   offsets_px: np.ndarray) -> np.ndarray:
    """Grey levels along each centre's normal (bilinear).

    Parameters
    ----------
    image : ndarray, shape (H, W)
        Grey image.
    xy : ndarray, shape (N, 2)
        Centres, px.
    normal : ndarray, shape (N, 2)
        Unit normals.
    offsets_px : ndarray, shape (M,)
        Positions along the normal, px.

    Returns
    -------
    ndarray, shape (N, M)
        ``image`` at ``xy + s * normal`` for each offset ``s`` (the border replicated).
    """
    s = np.asarray(offsets_px, np.float64)[None, :]
    mx = (xy[:, 0:1] + s * normal[:, 0:1]).astype(np.float32)
    my = (xy[:, 1:2] + s * normal[:, 1:2]).astype(np.float32)
    # Only the box the samples and their bilinear neighbours lie in is converted (a border
    # of the box is one of the image, replicated as before; the maps move by whole pixels).
    h, w = image.shape
    x0 = min(max(math.floor(float(mx.min())) - 1, 0), w - 1)
    y0 = min(max(math.floor(float(my.min())) - 1, 0), h - 1)
    x1 = max(min(math.ceil(float(mx.max())) + 2, w), x0 + 1)
    y1 = max(min(math.ceil(float(my.max())) + 2, h), y0 + 1)
    return cv2.remap(np.asarray(image[y0:y1, x0:x1], np.float32), mx - np.float32(x0),
                     my - np.float32(y0), cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def _trimmed_mean(a: np.ndarray, cut: float) -> np.ndarray:
    """Mean along axis 0 without the ``cut`` share at each end (``scipy.stats.trim_mean``,
    without its overhead: six calls a checked frame)."""
    n = len(a)
    lo = int(cut * n)
    return np.sort(a, axis=0)[lo:n - lo].mean(axis=0)


def _median_of_rows(a: np.ndarray) -> np.ndarray:
    """``np.median(a, axis=0)`` for a few rows, without its overhead."""
    k = a.shape[0]
    b = np.sort(a, axis=0)
    return b[k // 2] if k % 2 else 0.5 * (b[k // 2 - 1] + b[k // 2])


def _gauss(s: np.ndarray, centre: np.ndarray, width: np.ndarray) -> np.ndarray:
    return np.exp(-0.5 * ((s - centre) / width) ** 2)


class _Bins:
    """The centres' mean profiles by direction of their (consistently oriented) normals."""

    def __init__(self, image: np.ndarray, xy: np.ndarray, normal: np.ndarray,
                 params: ReflectionParams) -> None:
        ref = np.median(normal, axis=0)
        ref = ref / (np.linalg.norm(ref) or 1.0)
        self.normal = np.where(((normal @ ref) < 0)[:, None], -normal, normal)
        a0 = math.atan2(ref[1], ref[0])
        ang = np.arctan2(self.normal[:, 1], self.normal[:, 0])
        self.angle = (ang - a0 + np.pi) % (2.0 * np.pi) - np.pi
        k = params.bins
        edges = np.quantile(self.angle, np.linspace(0.0, 1.0, k + 1))
        self.label = np.clip(np.searchsorted(edges, self.angle, side="right") - 1, 0, k - 1)
        # Symmetric about the centre by construction: the odd misfit mirrors the samples.
        half = round(params.reach_px / params.step_px)
        self.s = params.step_px * np.arange(-half, half + 1, dtype=np.float64)
        prof = cross_profiles(image, xy, self.normal, self.s)
        # Centres whose core reaches the sensor's full scale: a clipped, flat-topped stripe.
        top = full_scale(image)
        core = np.abs(self.s) <= 0.5
        self.clipped = float((prof[:, core].max(axis=1) >= top - max(0.5, 1e-3 * top)).mean())
        self.count = np.bincount(self.label, minlength=k)
        # A trimmed mean: a glint or a droplet's rim in a few profiles does not make the bin.
        self.mean = np.array([_trimmed_mean(prof[self.label == j], 0.2)
                              if self.count[j] else np.zeros(self.s.size) for j in range(k)])
        nb = np.column_stack([np.bincount(self.label, self.normal[:, i], minlength=k)
                              for i in (0, 1)])
        nb = np.where(self.count[:, None] > 0, nb / np.maximum(self.count, 1)[:, None], ref)
        self.nbar = nb / np.linalg.norm(nb, axis=1, keepdims=True)
        self.centre_angle = np.array([median(self.angle[self.label == j])
                                      if self.count[j] else 0.0 for j in range(k)])
        self.weight = np.sqrt(self.count)[:, None]


def _model(p: np.ndarray, bins: _Bins, ghost: bool = True) -> np.ndarray:
    """The bins' modelled profiles (K, M) for parameters ``p``: ``[dx, dy, gain, blur]``
    (with ``ghost``) then per bin ``base, height, u, width, slope``."""
    return _model_and_jacobian(p, bins, ghost, jacobian=False)[0]


def _model_and_jacobian(p: np.ndarray, bins: _Bins, ghost: bool, jacobian: bool = True
                        ) -> tuple[np.ndarray, np.ndarray | None]:
    k = bins.nbar.shape[0]
    m = bins.s.size
    s = bins.s[None, :]
    g = 4 if ghost else 0
    base, height, u, width, slope = (p[g + i * k:g + (i + 1) * k][:, None] for i in range(5))
    a = s - u
    g1 = _gauss(s, u, width)
    total = g1
    if ghost:
        dx, dy, gain, blur = p[:4]
        delta = (bins.nbar @ np.array([dx, dy]))[:, None]
        wg = np.sqrt(width**2 + blur**2)
        b = a - delta
        g2 = _gauss(s, u + delta, wg)
        total = g1 + gain * g2
    out = base + slope * s + height * total
    if not jacobian:
        return out, None
    jac = np.zeros((k, m, p.size))
    rows = np.arange(k)
    jac[rows, :, g + rows] = 1.0
    jac[rows, :, g + k + rows] = total
    d_u = g1 * a / width**2
    d_w = g1 * a**2 / width**3
    if ghost:
        hg2 = height * gain * g2
        d_u = d_u + gain * g2 * b / wg**2
        d_w = d_w + gain * g2 * b**2 / wg**3 * (width / wg)
        along = hg2 * b / wg**2  # d/d(delta)
        jac[..., 0] = along * bins.nbar[:, 0:1]
        jac[..., 1] = along * bins.nbar[:, 1:2]
        jac[..., 2] = height * g2
        jac[..., 3] = hg2 * b**2 / wg**3 * (blur / wg)
    jac[rows, :, g + 2 * k + rows] = height * d_u
    jac[rows, :, g + 3 * k + rows] = height * d_w
    jac[rows, :, g + 4 * k + rows] = bins.s[None, :]
    return out, jac


@dataclass(frozen=True)
class _Solution:
    """A least-squares fit: parameters, half the weighted sum of squares, whether it met its
    tolerance within the evaluations it was given."""

    x: np.ndarray
    cost: float
    success: bool
    message: str


def _least_squares(bins: _Bins, p0: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                   ghost: bool, max_nfev: int = 40, ftol: float = 1e-8,
                   xtol: float = 1e-8) -> _Solution:
    """The model fitted to the bins' mean profiles, each bin weighted by its centres:
    Levenberg-Marquardt with Marquardt's scaling, steps projected into the bounds.

    A dense 34-parameter problem of about 220 residuals: each step is one solve of its normal
    equations, where scipy's trust-region solver took an SVD and its bookkeeping (30 ms a
    checked frame, most of the check's cost, against 2-3 ms here).
    """
    w = bins.weight[..., None]

    def evaluate(p: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        out, jac = _model_and_jacobian(p, bins, ghost)
        r = ((out - bins.mean) * bins.weight).ravel()
        return r, (jac * w).reshape(-1, p.size), 0.5 * float(r @ r)

    p = np.clip(p0, lo, hi)
    r, jac, cost = evaluate(p)
    damping, nfev = 1e-3, 1
    # Marquardt's scale, each parameter's largest curvature so far (MINPACK's): a parameter
    # that loses its grip for a step (an offset while the reflection's height passes zero)
    # is not let loose across the bounds.
    scale = np.zeros(p.size)
    while nfev < max_nfev:
        a, g = jac.T @ jac, jac.T @ r
        scale = np.maximum(scale, np.diag(a))
        scale = np.maximum(scale, 1e-9 * scale.max())
        try:
            step = np.linalg.solve(a + damping * np.diag(scale), -g)
        except np.linalg.LinAlgError:  # counted: a matrix that stays singular ends the fit
            damping *= 10.0
            nfev += 1
            continue
        trial = np.clip(p + step, lo, hi)
        r_t, jac_t, cost_t = evaluate(trial)
        nfev += 1
        if cost_t < cost:
            small = (cost - cost_t <= ftol * cost
                     or np.linalg.norm(trial - p) <= xtol * (xtol + np.linalg.norm(p)))
            p, r, jac, cost = trial, r_t, jac_t, cost_t
            damping = max(damping / 3.0, 1e-10)
            if small:
                return _Solution(p, cost, True, "converged")
        else:
            damping *= 4.0
            if damping > 1e10:  # no step lowers the misfit: at a minimum (or a bound)
                return _Solution(p, cost, True, "no smaller misfit nearby")
    # A reflection's fit converges in 8-18 evaluations; on a stripe without one the offset is
    # undetermined and the fit wanders: cut short, it fails.
    return _Solution(p, cost, False, f"not converged in {max_nfev} evaluations")


@dataclass(frozen=True)
class _Linear:
    """The linear screen: where the fits start, and how much a reflection can explain."""

    starts: list[tuple[float, float, float, float]]
    explained: float


def _starts(bins: _Bins, centre: np.ndarray, width: np.ndarray, reach: float, count: int
            ) -> _Linear:
    """The best ``count`` distinct reflections (dx, dy, gain, blur) on a grid of offsets and
    blurs, with stripe and reflection heights and background solved linearly per bin (each
    bin's line at ``centre`` (px) and ``width`` (px), its small shift and width change
    linearised): where the fits start; and the share of the single line's linear misfit that
    the best of them explains, the screen that clears a frame without a reflection.

    The fixed columns (1, the line, its shift and width, the background's slope) are the same
    for every grid point, so they are projected out once per bin; each reflection column then
    takes ``(g'Py)^2 / g'Pg`` off the misfit, with ``P`` the projection off the fixed columns.
    """
    y = bins.mean  # (K, M)
    grid = np.arange(-reach + 1.0, reach - 1.0 + 1e-9, 1.0)
    dx, dy = (a.ravel() for a in np.meshgrid(grid, grid))
    keep = np.hypot(dx, dy) >= 1.0
    dx, dy = dx[keep], dy[keep]
    s = bins.s[None, :]
    u, w = centre[:, None], width[:, None]
    g_main = _gauss(s, u, w)
    a = s - u
    ones = np.ones_like(g_main)
    fixed = np.stack([ones, g_main, g_main * a / w**2, g_main * a**2 / w**3, ones * s],
                     axis=-1)  # (K, M, 5)
    q, r = np.linalg.qr(fixed)
    # The line's height from the fixed columns' least squares: row 1 of their pseudo-inverse,
    # R^-1 Q^T.
    height_row = np.linalg.solve(r, q.transpose(0, 2, 1))[:, 1, :]  # (K, M)
    ry = y - np.einsum("kmj,kj->km", q, np.einsum("kmj,km->kj", q, y))
    plain = (ry * ry).sum(axis=1)  # (K,)
    plain_cost = float((plain * bins.count).sum())
    # Bins first (K, G, M): the projections are batched matrix products per bin.
    delta = bins.nbar[:, 0:1] * dx[None, :] + bins.nbar[:, 1:2] * dy[None, :]  # (K, G)
    qt = q.transpose(0, 2, 1)
    found: list[tuple[float, float, float, float, float]] = []
    for blur in (0.8, 1.6, 2.5):
        g_ghost = _gauss(s[:, None, :], (u + delta)[..., None],
                         np.sqrt(w**2 + blur**2)[..., None])
        rg = g_ghost - (g_ghost @ q) @ qt
        gg = (rg * rg).sum(axis=-1)  # (K, G)
        gy = (rg @ ry[..., None])[..., 0]
        coef = gy / np.maximum(gg, 1e-12)
        stripe = (y * height_row).sum(axis=1)[:, None] - coef * (
            g_ghost @ height_row[..., None])[..., 0]
        cost = ((plain[:, None] - coef * gy) * bins.count[:, None]).sum(axis=0)  # (G,)
        ratio = _median_of_rows(coef / np.maximum(stripe, 1e-9))
        cost[(ratio <= 0) | (stripe <= 0).any(axis=0) | (gg < 1e-9).any(axis=0)] = math.inf
        found += [(float(cost[i]), float(dx[i]), float(dy[i]), float(ratio[i]), blur)
                  for i in np.argsort(cost)[:count] if np.isfinite(cost[i])]
    starts: list[tuple[float, float, float, float]] = []
    for _, x, y_, gain, blur in sorted(found):
        if all(math.hypot(x - a, y_ - b) > 1.5 for a, b, _, _ in starts):
            starts.append((x, y_, min(max(gain, 0.01), 1.0), blur))
        if len(starts) == count:
            break
    best = min((f[0] for f in found), default=plain_cost)
    return _Linear(starts, 1.0 - best / plain_cost if plain_cost > 0 else 0.0)


def _odd_misfit(p: np.ndarray, bins: _Bins, ghost: bool) -> float:
    """The misfit's part that is odd across the stripe (one side against the other)."""
    r = (_model(p, bins, ghost) - bins.mean) * bins.weight
    return float(((r - r[:, ::-1]) ** 2).sum()) / 4.0


def fit_reflection(image: np.ndarray, xy: np.ndarray, normal: np.ndarray,
                   width_px: float, params: ReflectionParams | None = None,
                   lopsided: bool = False) -> Reflection:
    """Fit a reflection to the stripe's profiles and the pull it leaves at each centre.

    Parameters
    ----------
    image : ndarray, shape (H, W)
        Grey image (the frame the centres came from).
    xy : ndarray, shape (N, 2)
        The stripe's centres, px.
    normal : ndarray, shape (N, 2)
        Their unit normals (either sign).
    width_px : float
        The stripe's Gaussian sigma, px (a start for the fit).
    params : ReflectionParams, optional
        Settings.
    lopsided : bool
        The stripe is known to be lopsided (``StripePoints.balance``): the reflection may
        explain the profiles' asymmetry (``min_explained_asymmetry``) instead of the whole of
        their misfit to a single line (``min_explained``), some of which (glints, droplets'
        rims, a stripe clipped here and there) no reflection is asked to explain.

    Returns
    -------
    Reflection
        Truthy with ``shift_px`` (along the normals as given) when a reflection explains the
        profiles; falsy with the reason otherwise.
    """
    params = params or ReflectionParams()
    k = params.bins
    if len(xy) < k * params.min_per_bin:
        return Reflection(reason=f"{len(xy)} centres are too few to model a reflection "
                                 f"(need {k * params.min_per_bin})")
    bins = _Bins(image, xy, normal, params)
    if (bins.count < params.min_per_bin).any():
        return Reflection(reason="the centres' directions are too uneven to model a "
                                 "reflection")
    if bins.clipped > params.max_clipped:
        return Reflection(reason=f"the stripe's core is clipped at {bins.clipped:.0%} of its "
                                 "centres: a reflection beside a flat-topped stripe is not "
                                 "modelled")
    y = bins.mean
    base0 = np.median(y[:, :4], axis=1)
    height0 = np.maximum(y.max(axis=1) - base0, 1e-3)
    # The stripe's width as the extractor saw it, within what a profile of this reach holds.
    width0 = min(max(float(width_px), 0.6), params.reach_px / 3.0)
    zeros, widths = np.zeros(k), np.full(k, width0 + 0.2)
    if not np.isfinite(y).all():
        return Reflection(reason="the stripe's profiles are not finite")
    free = np.full(k, np.inf)
    lo0 = np.concatenate([-free, zeros, np.full(k, -2.0), np.full(k, 0.3), -free])
    hi0 = np.concatenate([free, free, np.full(k, 2.0), np.full(k, 6.0), free])
    plain = _least_squares(bins, np.clip(np.concatenate([base0, height0, zeros, widths, zeros]),
                                         lo0 + 1e-6, hi0 - 1e-6), lo0, hi0, ghost=False)
    base1, height1, u1, width1, slope1 = plain.x.reshape(5, k)
    linear = _starts(bins, u1, width1, params.reach_px, params.starts if lopsided else 1)
    y_var = float((((y - y.mean(axis=1, keepdims=True)) ** 2) * bins.count[:, None]).sum())
    misfit_share = 2.0 * plain.cost / y_var if y_var > 0 else 1.0
    if (not lopsided and misfit_share <= params.screen_max_misfit
            and linear.explained < params.min_explained - params.screen_margin):
        return Reflection(explained=linear.explained,
                          reason=f"a reflection explains at most {linear.explained:.0%} of the "
                                 f"profiles' misfit to a single line (need "
                                 f"{params.min_explained:.0%})")
    reach = params.reach_px
    lo = np.concatenate([[-reach, -reach, 0.0, 0.0], lo0])
    hi = np.concatenate([[reach, reach, 1.5, 5.0], hi0])
    sol = None
    # A lopsided stripe is worth every start; a routine check takes the best one. Each starts
    # from the single line's fit, its height shared with the reflection.
    for dx, dy, gain, blur in linear.starts:
        p0 = np.clip(np.concatenate([[dx, dy, gain, blur], base1, height1 / (1.0 + gain), u1,
                                     width1, slope1]), lo + 1e-6, hi - 1e-6)
        trial = _least_squares(bins, p0, lo, hi, ghost=True)
        if sol is None or trial.cost < sol.cost:
            sol = trial
    if sol is None:
        return Reflection(reason="no reflection fits the profiles")
    explained = 1.0 - sol.cost / plain.cost if plain.cost > 0 else 0.0
    odd_plain = _odd_misfit(plain.x, bins, ghost=False)
    asymmetry = 1.0 - _odd_misfit(sol.x, bins, ghost=True) / odd_plain if odd_plain > 0 else 0.0
    dx, dy, gain, blur = (float(v) for v in sol.x[:4])
    u = sol.x[4 + 2 * k:4 + 3 * k]
    found = dict(offset_px=(dx, dy), gain=gain, blur_px=blur, explained=explained,
                 explained_asymmetry=asymmetry)
    if lopsided and asymmetry < params.min_explained_asymmetry \
            and explained < params.min_explained:
        return Reflection(**found, reason=f"a reflection explains {asymmetry:.0%} of the "
                                          f"profiles' asymmetry and {explained:.0%} of their "
                                          f"misfit to a single line (need "
                                          f"{params.min_explained_asymmetry:.0%} or "
                                          f"{params.min_explained:.0%})")
    if not lopsided and explained < params.min_explained:
        return Reflection(**found, reason=f"a reflection explains {explained:.0%} of the "
                                          f"profiles' misfit to a single line (need "
                                          f"{params.min_explained:.0%})")
    if not sol.success:
        return Reflection(**found, reason=f"the reflection model did not converge "
                                          f"({sol.message})")
    if gain > params.max_gain:
        return Reflection(**found, reason=f"the second line is {gain:.2f} of the stripe's "
                                          "height: which one is the stripe is not clear")
    if np.max(np.abs(u)) > params.max_shift_px:
        return Reflection(**found, reason=f"the modelled pull ({np.max(np.abs(u)):.2f} px) "
                                          f"exceeds {params.max_shift_px:.2f} px")
    order = np.argsort(bins.centre_angle)
    shift = np.interp(bins.angle, bins.centre_angle[order], u[order])
    # Along the normals as given (the bins flipped some to one orientation).
    flipped = (bins.normal * normal).sum(axis=1) < 0
    return Reflection(**found, shift_px=np.where(flipped, -shift, shift))
