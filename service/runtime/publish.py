"""The fan-out: a measured frame becomes a record, and the record goes to the registers, the
feed (latest, history, live stream) and compensation, in that order."""

from __future__ import annotations

import math
import time
from dataclasses import replace

import numpy as np

from drivers.camera.base import Frame
from service.calibrate.master import corrected
from service.measure.result import MAX_UNCERTAINTY_MM, Measurement, Status
from service.measure.turning import about_the_form, centre_sigma_at, concentricity_check
from service.measurement_record import make_record
from service.runtime.calibration import CalibrationInUse
from service.runtime.compensating import CompensationService
from service.runtime.feed import MeasurementFeed, SequenceCounter
from service.runtime.job_service import JobService
from service.runtime.register_view import RegisterView


class Publisher:
    """Publishes each measured frame (called by the pipeline, in frame order, on the loop).

    Parameters
    ----------
    sequence : SequenceCounter
        The measurements' sequence numbers.
    feed, registers, compensation : MeasurementFeed, RegisterView, CompensationService
        Where the record goes.
    jobs : JobService
        Which feature of the job a diameter is.
    max_tir_mm : float
        Run-out beyond which measurements reach compensation held (``held_for_runout``).
    """

    def __init__(self, sequence: SequenceCounter, feed: MeasurementFeed,
                 registers: RegisterView, compensation: CompensationService, jobs: JobService,
                 max_tir_mm: float = 0.02) -> None:
        self.sequence, self.feed = sequence, feed
        self.registers, self.compensation, self.jobs = registers, compensation, jobs
        self.max_tir_mm = max_tir_mm
        self._feature: int | None = None
        registers.set_sequence(sequence.current)

    def __call__(self, frame: Frame, raw: Measurement, in_use: CalibrationInUse) -> None:
        m = judged(corrected(raw, in_use.correction), frame.frame_id, in_use,
                   frame.received_ns / 1e9)
        comp = self.compensation
        feature, refused = self.jobs.assign(m.diameter_mm if m else None)
        number = None if feature is None else feature.number
        if number is not None and number != self._feature:
            # A shoulder passed: no fused value across it (a frame without a diameter, or
            # one that fits no feature, leaves the window as it is).
            self.feed.restart_fusion()
            self._feature = number
        record = make_record(
            seq=self.sequence.next(), wall_time=time.time(), frame_id=frame.frame_id,
            raw=raw, m=m, fused=self.feed.fused(m),
            feature=self.jobs.feature_of(feature),  # the job's: its one source
            part_temp_c=comp.part_temp_c, alpha_per_k=comp.alpha_per_k,
            latency_ms=(time.monotonic_ns() - frame.received_ns) / 1e6,
            calibration_id=in_use.info.id,
            feature_number=number, refused=refused)
        self.registers.publish(record)  # first: the latency is frame -> registers
        self.feed.publish(record, m, frame, in_use.geometry)
        runout = in_use.runout.runout if in_use.runout is not None else None
        held = "runout" if runout is not None and runout.tir_mm > self.max_tir_mm else None
        if refused:
            held = "no_feature"  # a diameter that fits none of the features moves no tool
        comp.submit(record, frame.received_ns / 1e9, held=held, feature=feature)


def judged(m: Measurement, frame_id: int, in_use: CalibrationInUse, t_s: float
           ) -> Measurement:
    """``m`` (a frame taken at ``t_s``, seconds) judged for the surface's position
    (``positioned``), the axis tracker told the spindle axis it saw when ``m`` stands, and
    whether the position stays settled (``Settling``)."""
    m, axis_seen = positioned(m, frame_id, in_use)
    # A pass is a frame measured and checked; one refused as uncertain says nothing (an
    # eccentric surface about the spindle axis is mostly that).
    checked = m.free_center_mm is not None and m.free_center_cov is not None
    passed = None if not checked else True if m.status is Status.OK else \
        False if m.status is Status.NOT_CONCENTRIC else None
    in_use.settling.seen(t_s, m.status not in _OFF_SHAFT, passed)
    tracker = in_use.tracker
    if m and tracker is not None and axis_seen is not None:
        tracker.update(*axis_seen, m.diameter_mm)
    return m


_OFF_SHAFT = (Status.NO_STRIPE, Status.TOO_FEW_POINTS, Status.BAD_IMAGE)
"""A frame with one of these saw no shaft: it may have been taken out."""


def positioned(m: Measurement, frame_id: int, in_use: CalibrationInUse
               ) -> tuple[Measurement, tuple[np.ndarray, np.ndarray] | None]:
    """``m`` judged for the surface's position, and its free centre as the axis tracker is
    to see it (the spindle axis: less the run-out at the frame's angle; None without one).

    Without the frame's spindle angle, or before the run-out is known, the concentricity
    watch judges (``not_concentric``). With it, the free fit goes to the run-out tracker, and
    a frame measured about the surface's own centre is refused when its free centre lies off
    that run-out beyond the tracker's gate (a new part or clamping, before it is noticed)."""
    free = None
    if m.free_center_mm is not None and m.free_center_cov is not None:
        xx, xy, yy = m.free_center_cov
        free = (np.array(m.free_center_mm), np.array([[xx, xy], [xy, yy]]))
    runout, tracker = in_use.runout, in_use.tracker
    if runout is None or tracker is None or m.spindle_deg is None:
        return not_concentric(m, in_use), free
    known = runout.runout
    axis, axis_sigma = tracker.center()
    sigmas = runout.update(frame_id, m.spindle_deg, *free, axis) if free else float("nan")
    if not m.about_runout:
        # With the spindle's angle, a diameter about the spindle axis is not taken before the
        # run-out says the surface is concentric: one frame cannot tell an offset along its
        # arc's bisector from a change of diameter (a part clamped 50 um off passed five
        # frames in a row that way, 77 um wrong).
        m = not_concentric(m, in_use)
        if m:
            m = replace(m, status=Status.UNCERTAIN, reason=(
                f"the surface's run-out is not known yet ({runout.reason or 'learning'}): "
                "with the spindle's angle, a diameter is taken about the surface's own "
                "centre"))
        return m, free
    if m and sigmas > runout.gate:
        m = replace(m, status=Status.NOT_CONCENTRIC, reason=(
            f"this frame's centre lies {sigmas:.1f} sigma off the surface's run-out (limit "
            f"{runout.gate:.1f}): a new part or clamping?"))
    if known is not None and runout.form.lobes and m.status in (Status.OK, Status.UNCERTAIN) \
            and len(m.section_mm):
        # An out-of-round surface: its circle about the centre, with the form taken off.
        m = about_the_form(m, known.center_at(axis, m.spindle_deg), math.hypot(
            centre_sigma_at(known, m.spindle_deg), axis_sigma), m.spindle_deg,
            runout.form.lobes, MAX_UNCERTAINTY_MM)
    runout.form.add(m)
    if free is None or known is None:
        return m, None
    return m, (free[0] - (known.center_at(axis, m.spindle_deg) - axis), free[1])


def not_concentric(m: Measurement, in_use: CalibrationInUse) -> Measurement:
    """``m``, or ``m`` refused (``Status.NOT_CONCENTRIC``, the watch's reason) while the free
    fits of the last frames say the surface is not concentric with the tracked spindle axis
    (``turning.concentricity_check``): the ``axis`` method's diameter would be confidently
    wrong on it, and an offset from it would move the tool wrongly."""
    watch, tracker = in_use.concentricity, in_use.tracker
    if watch is None or tracker is None:
        return m
    centre, sigma = tracker.center()
    return concentricity_check(m, watch, centre, sigma)
