"""The spindle's turn from one frame to the next, estimated from the frames themselves.

Where neither the CNC nor an encoder says at which spindle angle a frame was taken, a surface
that is not concentric with the spindle still says it: its free-fit centre goes round the
spindle axis once a revolution. With frames taken at a steady frame rate and spindle speed,
frame *k* is at ``zero + k * step``; for each candidate ``step`` the centres are fitted by a
static offset (the free fits' own bias along each arc, the same at every angle) plus an
eccentricity turning with the spindle, and the step whose fit explains the centres best wins.
Only the step modulo a revolution matters to the measurement, so a frame rate faster or slower
than the spindle's is the same problem (the step is folded into (-180, 180] degrees).

A surface that runs true gives no signal, and a frame rate locked to the spindle (every frame
at the same angle, or a few) cannot show the turn: both are failures with a reason, never a
guess. The eccentricity's component along each arc's bisector is what the diameter needs and
what one frame cannot see; it comes from the frames at other angles, and the turn's direction
with it, so a direction the frames cannot tell is a failure too.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from service.measure.form import rotations, span_deg

MIN_SPAN_DEG = 270.0
MIN_CHI2_DROP = 50.0  # the turning eccentricity against a static offset alone
MIN_DIRECTION_CHI2 = 25.0  # the step against its mirror (the other way round)


@dataclass(frozen=True)
class SpindleStep:
    """The estimated turn per frame.

    Attributes
    ----------
    ok : bool
        Whether the frames tell it.
    deg_per_frame : float
        The spindle's turn from one frame to the next, right-handed about the calibration's
        axis direction, folded into (-180, 180].
    uncertainty_deg : float
        Its standard uncertainty.
    chi2_drop : float
        How much better the turning eccentricity explains the centres than a static offset.
    direction_chi2 : float
        How much better it does than the same turn the other way round.
    reason : str
        Why not, when ``ok`` is False.
    """

    ok: bool
    deg_per_frame: float = math.nan
    uncertainty_deg: float = math.nan
    chi2_drop: float = math.nan
    direction_chi2: float = math.nan
    reason: str = ""

    def angles(self, frame_index: np.ndarray) -> np.ndarray:
        """The frames' spindle angles (degrees, the first frame's zero arbitrary)."""
        return (np.asarray(frame_index, np.float64) * self.deg_per_frame) % 360.0


def _chi2(step_deg: float, index: np.ndarray, d: np.ndarray, w: np.ndarray) -> float:
    """The centres' chi-square about a static offset plus an eccentricity turning by
    ``step_deg`` a frame."""
    design = np.concatenate([rotations(np.radians(index * step_deg)),
                             np.broadcast_to(np.eye(2), (len(index), 2, 2))], axis=2)
    wa = w @ design
    normal = np.einsum("nji,njk->ik", design, wa)
    rhs = np.einsum("nji,nj->i", wa, d)
    try:
        p = np.linalg.solve(normal, rhs)
    except np.linalg.LinAlgError:
        return math.inf
    res = d - design @ p
    return float(np.einsum("ni,nij,nj->", res, w, res))


def estimate_spindle_step(centres_mm: np.ndarray, covs_mm2: np.ndarray, axis_mm: np.ndarray,
                          frame_index: np.ndarray) -> SpindleStep:
    """The spindle's turn per frame from free-fit centres of frames taken in order.

    Parameters
    ----------
    centres_mm : ndarray, shape (N, 2)
        The frames' free-fit centres in section coordinates.
    covs_mm2 : ndarray, shape (N, 2, 2)
        Their covariances.
    axis_mm : ndarray, shape (2,)
        The calibrated spindle axis in the same coordinates.
    frame_index : ndarray, shape (N,)
        Each frame's number in the sequence (steady frame rate and spindle speed).

    Returns
    -------
    SpindleStep
        Failures as values, with the reason.
    """
    c = np.asarray(centres_mm, np.float64).reshape(-1, 2)
    cov = np.asarray(covs_mm2, np.float64).reshape(-1, 2, 2)
    index = np.asarray(frame_index, np.float64).ravel()
    n = len(c)
    if n < 8 or len(cov) != n or len(index) != n:
        return SpindleStep(False, reason=f"{n} frames with a free fit, need 8 in order to "
                           "tell the spindle's turn")
    try:
        w = np.linalg.inv(cov)
    except np.linalg.LinAlgError:
        return SpindleStep(False, reason="a frame's centre covariance is singular")
    d = c - np.asarray(axis_mm, np.float64)
    mean = np.linalg.solve(w.sum(axis=0), np.einsum("nij,nj->i", w, d))
    res0 = d - mean
    chi2_static = float(np.einsum("ni,nij,nj->", res0, w, res0))
    span = max(float(index.max() - index.min()), 1.0)
    grid_step = min(0.5, 45.0 / span)  # an eighth of a minimum's width or finer
    grid = np.arange(-180.0 + grid_step, 180.0 + 1e-9, grid_step)
    usable = np.array([span_deg(index * s) >= MIN_SPAN_DEG for s in grid])
    if not usable.any():
        return SpindleStep(False, reason=f"{n} frames cannot cover {MIN_SPAN_DEG:.0f} degrees "
                           "of a revolution at any turn")
    chi2 = np.full(len(grid), math.inf)
    for k in np.flatnonzero(usable):
        chi2[k] = _chi2(float(grid[k]), index, d, w)
    k = int(np.argmin(chi2))
    from scipy.optimize import minimize_scalar  # here: 0.4 s at every start of a process

    fine = minimize_scalar(_chi2, bounds=(grid[k] - grid_step, grid[k] + grid_step),
                           args=(index, d, w), method="bounded",
                           options={"xatol": 1e-4 * grid_step})
    step = float(fine.x) if fine.fun <= chi2[k] else float(grid[k])
    best = min(float(fine.fun), float(chi2[k]))
    drop = chi2_static - best
    if drop < MIN_CHI2_DROP:
        return SpindleStep(False, chi2_drop=drop, reason=(
            "the frames' centres do not go round the spindle axis (the surface runs true, "
            "or the frame rate is locked to the spindle): its turn cannot be told from them"))
    if span_deg(index * step) < MIN_SPAN_DEG:
        return SpindleStep(False, step, chi2_drop=drop, reason=(
            f"at {step:.2f} degrees a frame the frames cover less than {MIN_SPAN_DEG:.0f} "
            "degrees of a revolution (a frame rate locked to the spindle)"))
    mirror = _chi2(-step, index, d, w)
    if mirror - best < MIN_DIRECTION_CHI2:
        return SpindleStep(False, step, chi2_drop=drop, direction_chi2=mirror - best, reason=(
            "the frames do not tell which way the spindle turns (the run-out is too small "
            "to show it along the arcs): give the frames' angles"))
    # Another turn that explains the centres nearly as well (another minimum of the scan: an
    # alias of a few frames a revolution) leaves the step open.
    left, right = np.roll(chi2, 1), np.roll(chi2, -1)
    minima = np.flatnonzero(np.isfinite(chi2) & (chi2 <= left) & (chi2 <= right))
    others = [float(chi2[m]) for m in minima if m != k]
    rival = min(others) if others else math.inf
    if rival - best < MIN_DIRECTION_CHI2:
        return SpindleStep(False, step, chi2_drop=drop, direction_chi2=mirror - best, reason=(
            f"two turns a frame explain the centres about as well ({step:.2f} and another): "
            "give the frames' angles"))
    h = max(grid_step * 0.1, 1e-4)
    curv = (_chi2(step + h, index, d, w) - 2.0 * best + _chi2(step - h, index, d, w)) / h ** 2
    sigma = math.sqrt(2.0 / curv) if curv > 0 else math.inf
    folded = (step + 180.0) % 360.0 - 180.0
    return SpindleStep(True, 180.0 if folded == -180.0 else folded, sigma, drop, mirror - best)
