"""Many frames of one turning surface: each frame's diameter about the surface's own centre,
the run-out and the roundness (``form``), and the concentricity check for frames with no
spindle angle.

The ``axis`` method pins each frame's circle to the spindle axis. A surface off that axis
(raw stock, a second clamping) breaks it; given each frame's spindle angle, the frames' free
fits tell where the surface's centre goes round (``form.fit_runout``), and each frame is
measured again about its own centre there. Without angles the spindle's turn per frame may be
estimated from the free fits themselves (``spindle_estimate``: frames in order at a steady
frame rate and speed); where it cannot be, the frames are only checked
(``concentricity_check``), and refused when they say the surface is not concentric. Pure:
images and angles in, measurements and figures out.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from service.measure import fit as fits
from service.measure.diameter import MeasureParams, axis_center, measure_frame
from service.measure.fit import order_along_arc
from service.measure.form import (
    ConcentricityWatch,
    Roundness,
    Runout,
    fit_runout,
    form_of_frames,
    rotation,
)
from service.measure.fuse import Fused, fuse
from service.measure.geometry import RigGeometry
from service.measure.result import Measurement, Method, Status
from service.measure.spindle_estimate import SpindleStep, estimate_spindle_step

FORM_SIGNIFICANCE = 4.5
"""A harmonic of the form taken off the frames' points stands above this many of its standard
uncertainties (``form.roundness``'s own threshold for RONt)."""

FORM_ROUNDS = 1
"""Rounds of form and run-out estimated in turn: in the simulator a second round moved TIR by
0.3 um at most and the diameters' mean error by 0.07 um."""

MIN_CENTRE_SIGMA_MM = 0.5e-3
"""The surface's centre at a frame is taken as known no better than this: the run-out fit's
own uncertainty shrinks with the frames, its model's errors (a bent part, whirl) do not."""


def concentricity_check(m: Measurement, watch: ConcentricityWatch, axis_mm: np.ndarray,
                        axis_sigma_mm: float) -> Measurement:
    """``m``, or ``m`` refused as ``NOT_CONCENTRIC`` when the free fits of the frames so far
    (``watch``, fed with this one's) say the surface is not concentric with the spindle axis
    at ``axis_mm`` (section mm, known to ``axis_sigma_mm``), or this frame's own free centre
    lies beyond the watch's ``frame_limit`` sigmas of it. Every frame's free fit counts,
    refused ones too (most frames of an eccentric surface are refused as uncertain)."""
    sigmas = math.nan
    if m.free_center_mm is not None and m.free_center_cov is not None:
        xx, xy, yy = m.free_center_cov
        s2 = axis_sigma_mm**2
        sigmas = watch.update(np.array(m.free_center_mm) - axis_mm,
                              np.array([[xx + s2, xy], [xy, yy + s2]]))
    if m.status is not Status.OK:
        return m
    verdict = watch.verdict()
    if not verdict.concentric:
        return replace(m, status=Status.NOT_CONCENTRIC, reason=verdict.reason)
    if sigmas > watch.frame_limit:
        return replace(m, status=Status.NOT_CONCENTRIC, reason=(
            f"the surface is not concentric with the spindle axis: this frame's own centre "
            f"lies {sigmas:.1f} sigma off it (limit {watch.frame_limit:.1f})"))
    return m


@dataclass(frozen=True)
class TurningFrames:
    """What the frames of one turning surface say.

    Attributes
    ----------
    measurements : list of Measurement
        Each frame's, about the surface's own centre at its spindle angle when the run-out
        is known, else the ``axis`` method's refused as not concentric where it is not.
    runout : Runout
        The surface's centre relative to the spindle axis.
    fused : Fused
        The frames' diameters combined.
    roundness : Roundness or None
        The form over the material's angle, when asked for.
    axis_check : Runout or None
        The run-out fitted with the spindle axis free (its ``axis_shift_mm``: where the
        frames put the axis relative to the calibrated one), when the angles go round.
    spindle : SpindleStep or None
        The turn per frame estimated from the frames, when no angles were given.
    """

    measurements: list[Measurement]
    runout: Runout
    fused: Fused
    roundness: Roundness | None = None
    axis_check: Runout | None = None
    spindle: SpindleStep | None = None


def centre_sigma_at(runout: Runout, spindle_deg: float) -> float:
    """The standard uncertainty of the surface's centre at a spindle angle (mm; the larger
    axis of its covariance), from the run-out fit's parameter covariance, inflated by its
    chi-square when that exceeds 1, and at least ``MIN_CENTRE_SIGMA_MM``."""
    p_cov = runout.parameter_cov
    j = np.hstack([rotation(math.radians(spindle_deg)), np.eye(2)])[:, :p_cov.shape[0]]
    cov = j @ p_cov @ j.T * max(1.0, runout.chi2_per_dof)
    return max(math.sqrt(max(float(np.linalg.eigvalsh(cov)[-1]), 0.0)), MIN_CENTRE_SIGMA_MM)


def measure_turning(images: Sequence[np.ndarray], geometry: RigGeometry,
                    spindle_deg: Sequence[float] | None, params: MeasureParams | None = None,
                    form: bool = False, upr: int = 50) -> TurningFrames:
    """Measure frames of one surface taken at known spindle angles.

    A first pass measures each frame by ``axis`` for its free fit; the run-out about the
    calibrated spindle axis follows from the free centres and the angles (and, as a check,
    the axis itself when the angles cover half a revolution); a second pass measures each frame
    about the surface's centre at its angle, as uncertain as the run-out leaves it. The
    second pass's points give the radius over the material's angle; where harmonics of it
    stand above their noise, they are taken off every frame's points and the run-out and the
    circles fitted again. ``form`` returns that roundness too.

    Parameters
    ----------
    images : sequence of ndarray
        The frames, in the order taken.
    geometry : RigGeometry
        Calibration (with its axis point).
    spindle_deg : sequence of float or None
        Each frame's spindle angle, right-handed about the calibration's axis direction;
        None: estimated from the frames (in the order taken, at a steady frame rate and
        spindle speed), and where that fails each frame is checked for concentricity.
    params : MeasureParams, optional
        Settings.
    form : bool
        Also assemble the roundness.
    upr : int
        The roundness filter's undulations per revolution.
    """
    # The free fits are what tells where the surface's centre goes.
    params = replace(params or MeasureParams(), free_fit=True)
    angles = None if spindle_deg is None else np.asarray(spindle_deg, np.float64).ravel()
    if angles is not None and len(angles) != len(images):
        raise ValueError(f"{len(images)} frames but {len(angles)} spindle angles")
    axis = axis_center(geometry)
    if axis is None:
        failed = Runout(False, frames=len(images), reason="the calibration has no axis point")
        ms = [measure_frame(im, geometry, Method.AXIS, params) for im in images]
        return TurningFrames(ms, failed, fuse(ms))
    first, near = [], None
    for im in images:
        m = measure_frame(im, geometry, Method.AXIS, params, near=near)
        near = m.stripe_px
        first.append(m)
    use = [i for i, m in enumerate(first)
           if m.free_center_mm is not None and m.free_center_cov is not None]
    centres = np.array([first[i].free_center_mm for i in use]).reshape(-1, 2)
    covs = np.array([[[c[0], c[1]], [c[1], c[2]]] for c in
                     (first[i].free_center_cov for i in use)]).reshape(-1, 2, 2)
    spindle = None
    if angles is None:
        spindle = estimate_spindle_step(centres, covs, axis, np.array(use))
        if not spindle.ok:
            watch = ConcentricityWatch(window=max(len(images), 1))
            ms = [concentricity_check(m, watch, axis, params.axis_sigma_mm) for m in first]
            return TurningFrames(ms, Runout(False, frames=len(use), reason=spindle.reason),
                                 fuse(ms), spindle=spindle)
        angles = spindle.angles(np.arange(len(images)))
    # About the calibrated axis: fitting the axis too lets the free fits' own bias along
    # each arc's bisector (a micrometre or two, the same at every angle) move it, and every
    # diameter with it (3-5 um in the simulator); the frames' axis is reported as a check.
    runout = fit_runout(centres, covs, angles[use], axis, fit_axis=False)
    axis_check = fit_runout(centres, covs, angles[use], axis, fit_axis=True)
    if not runout.ok:
        watch = ConcentricityWatch(window=max(len(images), 1))
        ms = [concentricity_check(m, watch, axis, params.axis_sigma_mm) for m in first]
        return TurningFrames(ms, runout, fuse(ms), axis_check=axis_check, spindle=spindle)
    second, near = [], None
    for im, theta in zip(images, angles, strict=True):
        centre = runout.center_at(axis, float(theta))
        m = measure_frame(im, geometry, Method.AXIS, params,
                          center_prior=(centre, centre_sigma_at(runout, float(theta))),
                          near=near)
        near = m.stripe_px
        second.append(m)
    shape = roundness_of(second, angles, upr)
    for _ in range(FORM_ROUNDS):
        # A surface out of round moves each arc's free centre and bends its circle: with the
        # form known, take it off every frame's points and fit again.
        lobes = significant_lobes(shape)
        if not lobes:
            break
        again, refitted = _about_the_form(second, angles, axis, lobes, params)
        if not again.ok:
            break
        runout, second = again, refitted
        shape = roundness_of(second, angles, upr)
    return TurningFrames(second, runout, fuse(second), shape if form else None, axis_check,
                         spindle)


def significant_lobes(shape: Roundness) -> list[tuple[int, float, float]]:
    """The harmonics (order, amplitude mm, phase rad) that stand above their noise."""
    if not shape.ok or not shape.dominant_order:
        return []
    return [(h.order, h.amplitude_mm, math.radians(h.phase_deg)) for h in shape.harmonics
            if h.amplitude_mm > FORM_SIGNIFICANCE * h.amplitude_uncertainty_mm]


def _off_form(points_mm: np.ndarray, centre: np.ndarray, spindle_deg: float,
              lobes: list[tuple[int, float, float]]) -> np.ndarray:
    """Points moved radially about ``centre`` by the form at their material angles."""
    d = points_mm - centre
    r = np.hypot(d[:, 0], d[:, 1])
    beta = np.arctan2(d[:, 1], d[:, 0]) - math.radians(spindle_deg)
    dr = sum(a * np.cos(k * beta - ph) for k, a, ph in lobes)
    return points_mm - (dr / np.maximum(r, 1e-12))[:, None] * d


def _about_the_form(ms: list[Measurement], angles: np.ndarray, axis: np.ndarray,
                    lobes: list[tuple[int, float, float]], params: MeasureParams
                    ) -> tuple[Runout, list[Measurement]]:
    """The run-out from free fits of the points with the form taken off, and each frame's
    circle about its centre then (``fit.fit_axis_prior`` on those points: the diameter of
    the form's reference circle)."""
    def refit(m: Measurement) -> bool:
        # Only frames whose circle stood but for its uncertainty: the others' checks (the
        # arc, the points' scatter) stand as they were.
        return m.status in (Status.OK, Status.UNCERTAIN) and m.center_mm is not None \
            and len(m.section_mm) >= params.min_points

    centres, covs, use = [], [], []
    for i, (m, theta) in enumerate(zip(ms, angles, strict=True)):
        if not refit(m):
            continue
        pts = _off_form(m.section_mm, np.asarray(m.center_mm), theta, lobes)
        free = fits.fit_geometric(pts)
        if free:
            cov = fits.circle_covariance(pts, free.center, free.radius, inliers=free.inliers)
            centres.append(free.center)
            covs.append(cov[:2, :2])
            use.append(i)
    runout = fit_runout(np.array(centres).reshape(-1, 2), np.array(covs).reshape(-1, 2, 2),
                        angles[use], axis, fit_axis=False)
    if not runout.ok:
        return runout, ms
    out = []
    for m, theta in zip(ms, angles, strict=True):
        if not refit(m):
            out.append(m)
            continue
        centre = runout.center_at(axis, float(theta))
        out.append(about_the_form(m, centre, centre_sigma_at(runout, float(theta)),
                                  float(theta), lobes, params.max_uncertainty_mm))
    return runout, out


def about_the_form(m: Measurement, centre_mm: np.ndarray, centre_sigma_mm: float,
                   spindle_deg: float, lobes: list[tuple[int, float, float]],
                   max_uncertainty_mm: float) -> Measurement:
    """``m``'s circle fitted again about the surface's centre at its spindle angle (known to
    ``centre_sigma_mm``) with the form's ``lobes`` (order, amplitude mm, phase rad) taken off
    its points: the diameter of the form's reference circle, not of the arc's share of the
    lobes (``fit.fit_axis_prior``)."""
    pts = _off_form(m.section_mm, np.asarray(centre_mm, np.float64), spindle_deg, lobes)
    circ = fits.fit_axis_prior(pts, centre_mm, centre_sigma_mm)
    if not circ:
        return replace(m, status=Status.FIT_FAILED, diameter_mm=None, reason=circ.reason)
    std = 2.0 * circ.radius_std
    ok = bool(np.isfinite(std) and std <= max_uncertainty_mm)
    return replace(
        m, status=Status.OK if ok else Status.UNCERTAIN,
        diameter_mm=float(circ.diameter) if ok else None,
        center_mm=(float(circ.center[0]), float(circ.center[1])),
        uncertainty_mm=float(std) if np.isfinite(std) else None,
        reason="" if ok else f"diameter uncertain by {std * 1000:.1f} um (limit "
        f"{max_uncertainty_mm * 1000:.1f} um) with the surface's form taken off",
        note="measured with the surface's form taken off")


def about_centre(points_mm: np.ndarray, centre_mm: np.ndarray, spindle_deg: float
                 ) -> tuple[np.ndarray, np.ndarray]:
    """A frame's points as (material angle rad, radius mm) about the surface's centre at its
    spindle angle, in their order along the arc (the noise's correlation is read along it)."""
    d = np.asarray(points_mm, np.float64) - np.asarray(centre_mm, np.float64)
    d = d[order_along_arc(d, np.zeros(2))]
    return (np.arctan2(d[:, 1], d[:, 0]) - math.radians(spindle_deg),
            np.hypot(d[:, 0], d[:, 1]))


def roundness_of(ms: list[Measurement], angles: np.ndarray, upr: int) -> Roundness:
    """Every fitted frame's points (as its fit took them) as radii about its own centre at
    their material angles (the angle in the section less the frame's spindle angle), each
    frame with its own mean radius (``form.form_of_frames``)."""
    # Frames refused only as uncertain count too: a form the run-out does not model (lobes)
    # leaves most of them uncertain until it is known.
    kept = [about_centre(m.section_mm, np.asarray(m.center_mm), float(theta))
            for m, theta in zip(ms, angles, strict=True)
            if m.status in (Status.OK, Status.UNCERTAIN) and m.center_mm is not None
            and len(m.section_mm) > 0]
    if not kept:
        return Roundness(False, reason="no frame was measured")
    return form_of_frames(kept, upr)
