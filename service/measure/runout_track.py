"""The turning surface's run-out followed frame by frame, for a service that knows each frame's
spindle angle (``SpindleAngles``): where the surface's centre is at the next frame's angle,
so that the frame is measured about it (``form.fit_runout`` over the last free fits).

The ``axis`` method pins each frame's circle to the spindle axis, right for the surface being
turned and wrong for one that is not concentric with it (raw stock, a second clamping). With
the angle known, the last ``window`` free-fit centres tell the eccentricity about the tracked
axis; once they cover ``min_span_deg`` of a revolution and the fit explains them, the run-out
is *known* and each frame gets the surface's centre at its angle as its prior, with the fit's
uncertainty there. Before that (the first revolution, a frame rate locked to the spindle) it
gives nothing, and the frames stay under the concentricity watch. A free centre that leaves
the known run-out beyond ``gate`` sigmas ``lost_after`` times in a row (a new part, another
clamping) forgets it and learns again; so does a frame number that goes backwards (the
camera started again: the angle's phase is lost with it).
Pure: centres and angles in, a prior out.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from service.measure.form import (
    Roundness,
    Runout,
    fit_runout,
    form_of_frames,
    rotations,
    span_deg,
)
from service.measure.result import Measurement, Status
from service.measure.turning import (
    MIN_CENTRE_SIGMA_MM,
    about_centre,
    centre_sigma_at,
    significant_lobes,
)


@dataclass(frozen=True)
class SpindleAngles:
    """Each frame's spindle angle from its camera frame number, the camera triggered by the
    spindle's encoder every ``deg_per_frame`` degrees (a rotary encoder's pulses divided down
    to the frame trigger). Angles count right-handed about the calibration's
    ``axis.direction``; ``zero_deg`` is the angle at frame number 0 (unknown for a camera
    whose numbers start anywhere: the run-out's phase is then relative, its size is not).
    """

    deg_per_frame: float
    zero_deg: float = 0.0

    def at(self, frame_id: int) -> float:
        """The spindle angle of frame ``frame_id``, degrees in [0, 360)."""
        return (self.zero_deg + frame_id * self.deg_per_frame) % 360.0



@dataclass
class Settling:
    """Whether the surface under the laser is still the one whose position was checked, so
    that a frame may go without a free fit of its own.

    Each frame's free fit is what judges its position (the concentricity watch, the run-out's
    gate); above ``pipeline.RUNOUT_FREE_FIT_HZ`` frames a second (``FREE_FIT_HZ`` without the
    spindle's angle) the service fits freely only that often once the position is
    *settled*: ``frames`` free fits in a row passed it. Anything
    that may mean another surface unsettles it until that many pass again, every frame
    fitted freely meanwhile: a free fit refused as off the axis or its run-out, a frame with
    no stripe on a shaft (a part taken out, the laser blocked), a pause of more than
    ``max_gap_s`` between frames (the spindle stopped: an encoder-triggered camera takes
    none), another calibration.
    """

    frames: int = 10
    max_gap_s: float = 0.5
    _streak: int = 0
    _last_s: float | None = None

    @property
    def settled(self) -> bool:
        """Whether a frame may go without its own free fit."""
        return self._streak >= self.frames

    def seen(self, t_s: float, on_shaft: bool, passed: bool | None) -> None:
        """A frame taken at ``t_s`` (seconds): whether its stripe lay on the shaft, and
        whether its free fit passed the position check (None: it had none)."""
        if self._last_s is not None and t_s - self._last_s > self.max_gap_s:
            self._streak = 0
        self._last_s = t_s
        if not on_shaft or passed is False:
            self._streak = 0
        elif passed:
            self._streak += 1


@dataclass
class FormFrames:
    """Frames measured about the surface's own centre, kept for its roundness (the radius over
    the material's angle, ``form.form_of_frames``, each frame with its own mean radius): the
    latest of each ``bins``-th of a revolution of spindle angle, so that they cover the
    material's angles whatever the frame rate and the spindle's speed make of the frames'
    angles, and a frame seen again (a camera replaying its frames) replaces itself rather
    than counting twice. Each keeps its points as material angles and radii (a few kB).

    Parameters
    ----------
    bins : int
        Frames kept, one per ``360 / bins`` degrees of spindle angle.
    """

    bins: int = 360
    added: int = 0
    lobes: list = field(default_factory=list)
    """The harmonics (order, amplitude mm, phase rad) of the last form made that stand above
    their noise: taken off the points of the frames that follow (``turning.about_the_form``)."""
    _kept: dict = field(default_factory=dict, repr=False)

    def add(self, m: Measurement) -> None:
        """A frame measured about the surface's centre at its spindle angle (others are not
        taken: their points are about the spindle axis)."""
        if not m.about_runout or m.spindle_deg is None or m.center_mm is None \
                or m.status not in (Status.OK, Status.UNCERTAIN) or len(m.section_mm) == 0:
            return
        slot = int(m.spindle_deg % 360.0 * self.bins / 360.0) % self.bins
        self._kept[slot] = about_centre(m.section_mm, np.asarray(m.center_mm), m.spindle_deg)
        self.added += 1

    def clear(self) -> None:
        """Forget the frames (another part, another clamping)."""
        self._kept.clear()
        self.lobes = []

    def roundness(self, upr: int = 50) -> Roundness:
        """The form of the frames kept (``ok`` False with the reason when they do not cover
        the material's angles); its significant harmonics become ``lobes``."""
        if not self._kept:
            return Roundness(False, reason="no frame measured about the surface's centre yet")
        shape = form_of_frames(list(self._kept.values()), upr)
        self.lobes = significant_lobes(shape)
        return shape


@dataclass
class RunoutTracker:
    """The surface's run-out from the last free fits at known spindle angles.

    Parameters
    ----------
    window : int
        Free fits the run-out is fitted from (a free fit every frame: 2.4 s at 100 frames a
        second; the run-out's uncertainty shrinks with the square root of their number).
    refit_every : int
        Once the run-out is known, it is fitted again every this many free fits taken (a fit
        of the window costs about 0.7 ms on the event loop); each is judged by the gate as
        it comes.
    min_frames : int
        Free fits needed before it is known.
    min_span_deg : float
        Their spindle angles must cover this much of a revolution: a frame rate locked to
        the spindle (every frame at one angle) never makes it known.
    max_chi2 : float
        The fit's chi-square per degree of freedom beyond which the centres do not go round
        as one eccentricity (whirl, a bent part, a form that moves the arcs' centres): not
        known. Below it, the centre's uncertainty grows with it (``centre_sigma_at``).
    gate : float
        A free centre this many sigmas off the run-out's prediction does not fit it.
    lost_after : int
        That many in a row and the run-out is forgotten.
    """

    window: int = 240
    refit_every: int = 8
    min_frames: int = 12
    min_span_deg: float = 270.0
    max_chi2: float = 9.0
    gate: float = 5.0
    lost_after: int = 3
    form: FormFrames = field(default_factory=FormFrames)
    """The frames measured about the surface's centre, for its roundness (cleared with it)."""
    resets: int = 0
    reason: str = "no free fit at a known spindle angle yet"
    _fits: deque = field(default_factory=deque, repr=False)
    _runout: Runout | None = field(default=None, repr=False)
    _misses: int = 0
    _since_fit: int = 0
    _last_id: int | None = None
    _axis: np.ndarray | None = field(default=None, repr=False)

    def reset(self, why: str) -> None:
        """Forget the run-out (``why`` says so until it is known again)."""
        self._fits.clear()
        self.form.clear()
        self._runout, self._misses = None, 0
        self.reason = why
        self.resets += 1

    @property
    def runout(self) -> Runout | None:
        """The run-out, when known."""
        return self._runout

    def _see(self, frame_id: int) -> None:
        if self._last_id is not None and frame_id < self._last_id:
            self.reset(f"the camera's frame numbers went back ({self._last_id} to {frame_id}):"
                       " the spindle angle's phase is lost with them")
        self._last_id = frame_id

    def offset_sigmas(self, spindle_deg: float, centre_mm: np.ndarray, cov_mm2: np.ndarray,
                      axis_mm: np.ndarray) -> float:
        """How many sigmas a free centre lies off the known run-out at its angle (NaN when
        the run-out is not known)."""
        r = self._runout
        return math.nan if r is None else float(_sigmas(r, spindle_deg, centre_mm, cov_mm2,
                                                         axis_mm)[0])

    def update(self, frame_id: int, spindle_deg: float, centre_mm: np.ndarray,
               cov_mm2: np.ndarray, axis_mm: np.ndarray) -> float:
        """One frame's free-fit centre (section mm) and covariance at its spindle angle,
        about the tracked spindle axis ``axis_mm``; returns how many sigmas it lies off the
        run-out known before it (NaN when none was). A centre beyond ``gate`` is not taken."""
        self._see(frame_id)
        c = np.asarray(centre_mm, np.float64).reshape(2)
        cov = np.asarray(cov_mm2, np.float64).reshape(2, 2)
        if not (np.isfinite(c).all() and np.isfinite(cov).all()):
            return math.nan
        sigmas = self.offset_sigmas(spindle_deg, c, cov, axis_mm)
        if sigmas > self.gate:
            self._misses += 1
            if self._misses >= self.lost_after:
                self.reset(f"the surface's centre left its run-out ({sigmas:.1f} sigma, "
                           f"{self.lost_after} frames in a row): a new part or clamping")
            return sigmas
        self._misses = 0
        self._fits.append((float(spindle_deg), c, cov))
        while len(self._fits) > self.window:
            self._fits.popleft()
        self._since_fit += 1
        if self._runout is None or self._since_fit >= self.refit_every:
            self._since_fit = 0
            self._fit(np.asarray(axis_mm, np.float64))
        return sigmas

    def _fit(self, axis_mm: np.ndarray) -> None:
        self._axis = axis_mm
        n = len(self._fits)
        if n < self.min_frames:
            self._runout = None
            self.reason = f"{n} free fits at known spindle angles, need {self.min_frames}"
            return
        deg = np.array([f[0] for f in self._fits])
        span = span_deg(deg)
        if span < self.min_span_deg:
            self._runout = None
            self.reason = (f"the spindle angles of the last {n} free fits cover {span:.0f} "
                           f"degrees, need {self.min_span_deg:.0f} (a frame rate locked to "
                           "the spindle never goes round)")
            return
        fixed = fit_runout(np.array([f[1] for f in self._fits]),
                           np.array([f[2] for f in self._fits]), deg, axis_mm, fit_axis=False)
        check = None if fixed.ok and fixed.chi2_per_dof <= self.max_chi2 else self.axis_check()
        if check is not None and check["chi2_per_dof"] <= self.max_chi2:
            # The window goes round one axis: off the tracked one, it is the axis that is
            # wrong (the calibration), not the part that changed.
            dx, dy = (v * 1000.0 for v in check["shift_mm"])
            if math.hypot(dx, dy) > max(4.0 * check["shift_uncertainty_mm"] * 1000.0, 2.0):
                self._runout = None
                self.reason = (f"the surface goes round an axis ({dx:+.1f}, {dy:+.1f}) um off "
                               "the tracked spindle axis: check the calibration's axis (a "
                               "master check, or calibrate the axis again)")
                return
        r = self._fit_pruned(axis_mm)
        if not r.ok:
            self._runout, self.reason = None, r.reason
        elif r.chi2_per_dof > self.max_chi2:
            self._runout = None
            self.reason = (f"the surface's centre does not go round as one eccentricity "
                           f"(chi-square {r.chi2_per_dof:.1f} per degree of freedom, limit "
                           f"{self.max_chi2:g}): whirl, a bent part, or a form it cannot take")
        else:
            self._runout, self.reason = r, ""

    def _fit_pruned(self, axis_mm: np.ndarray, passes: int = 3) -> Runout:
        """The run-out from the window, less the free fits that lie beyond ``gate`` of it (a
        window that began before another part or clamping holds some of the last one's)."""
        fits = list(self._fits)
        r = Runout(False, reason="no free fit")
        for _ in range(passes):
            deg = np.array([f[0] for f in fits])
            c = np.array([f[1] for f in fits])
            cov = np.array([f[2] for f in fits])
            r = fit_runout(c, cov, deg, axis_mm, fit_axis=False)
            if not r.ok:
                return r
            ok = _sigmas(r, deg, c, cov, axis_mm) <= self.gate
            if ok.all():
                return r
            if ok.sum() < self.min_frames or span_deg(deg[ok]) < self.min_span_deg:
                return Runout(False, reason=f"{int((~ok).sum())} of the last {len(fits)} free "
                              "fits lie off the run-out of the others: a change of part or "
                              "clamping while it was being learnt")
            fits = [f for f, keep in zip(fits, ok, strict=True) if keep]
            self._fits = deque(fits)
        return r

    def prior_at(self, frame_id: int, spindle_deg: float, axis_mm: np.ndarray,
                 axis_sigma_mm: float) -> tuple[np.ndarray, float] | None:
        """The surface's centre at this frame's angle and its standard uncertainty (the
        run-out's there and the axis's), or None while the run-out is not known."""
        r = self._runout
        if r is None or (self._last_id is not None and frame_id < self._last_id):
            return None
        return (r.center_at(axis_mm, spindle_deg),
                math.hypot(centre_sigma_at(r, spindle_deg), axis_sigma_mm))

    def status(self) -> dict:
        """JSON-ready: the run-out when known (eccentricity, its phase, TIR, uncertainties)
        or why not."""
        r = self._runout
        out: dict = {"known": r is not None, "frames": len(self._fits), "resets": self.resets,
                     "reason": self.reason or None}
        if r is not None:
            out.update(eccentricity_mm=r.eccentricity_mm, eccentricity_deg=r.eccentricity_deg,
                       tir_mm=r.tir_mm, tir_uncertainty_mm=r.tir_uncertainty_mm,
                       eccentricity_deg_uncertainty=r.eccentricity_deg_uncertainty,
                       chi2_per_dof=r.chi2_per_dof)
        out["axis_check"] = self.axis_check()
        return out

    def axis_check(self) -> dict | None:
        """Where the window's free fits put the spindle axis relative to the tracked one
        (the run-out fitted with the axis free: section mm, with its standard uncertainty),
        None when they cannot tell. A check of the calibrated axis on a surface just turned,
        not a correction: the free fits' own bias along their arcs' bisector (a micrometre
        or two) moves it too."""
        if self._axis is None or len(self._fits) < 3:
            return None
        f = list(self._fits)
        r = fit_runout(np.array([x[1] for x in f]), np.array([x[2] for x in f]),
                       np.array([x[0] for x in f]), self._axis, fit_axis=True)
        if not r.ok:
            return None
        xx, _, yy = r.axis_shift_cov
        return {"shift_mm": list(r.axis_shift_mm),
                "shift_uncertainty_mm": math.sqrt(max(xx + yy, 0.0) / 2.0),
                "chi2_per_dof": r.chi2_per_dof}





def _sigmas(r: Runout, spindle_deg: np.ndarray | float, centre_mm: np.ndarray,
            cov_mm2: np.ndarray, axis_mm: np.ndarray) -> np.ndarray:
    """How many sigmas free centres (N, 2) lie off a run-out's centre at their angles (N,):
    their covariances (N, 2, 2) and the run-out's uncertainty there (``centre_sigma_at``,
    for all at once); infinite where they cannot be used."""
    th = np.radians(np.atleast_1d(np.asarray(spindle_deg, np.float64)))
    c = np.asarray(centre_mm, np.float64).reshape(-1, 2)
    cov = np.asarray(cov_mm2, np.float64).reshape(-1, 2, 2)
    e = r.eccentricity_mm * np.column_stack([np.cos(th + math.radians(r.eccentricity_deg)),
                                             np.sin(th + math.radians(r.eccentricity_deg))])
    d = c - (np.asarray(axis_mm, np.float64) + np.asarray(r.axis_shift_mm) + e)
    p_cov = r.parameter_cov
    jac = rotations(th)
    if p_cov.shape[0] == 4:
        jac = np.concatenate([jac, np.broadcast_to(np.eye(2), (len(th), 2, 2))], axis=2)
    model = jac @ p_cov @ jac.transpose(0, 2, 1) * max(1.0, r.chi2_per_dof)
    a, b, cc = model[:, 0, 0], model[:, 0, 1], model[:, 1, 1]
    top = (a + cc) / 2.0 + np.sqrt(((a - cc) / 2.0) ** 2 + b**2)
    s2 = np.maximum(top, MIN_CENTRE_SIGMA_MM**2)
    total = cov + s2[:, None, None] * np.eye(2)
    det = total[:, 0, 0] * total[:, 1, 1] - total[:, 0, 1] * total[:, 1, 0]
    m2 = (d[:, 0] ** 2 * total[:, 1, 1] - 2.0 * d[:, 0] * d[:, 1] * total[:, 0, 1]
          + d[:, 1] ** 2 * total[:, 0, 0]) / np.where(det > 0, det, np.nan)
    return np.where(np.isfinite(m2) & (m2 >= 0), np.sqrt(np.abs(m2)), np.inf)
