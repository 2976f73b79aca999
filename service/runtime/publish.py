"""The fan-out: a measured frame becomes a record, and the record goes to the registers, the
feed (latest, history, live stream) and compensation, in that order."""

from __future__ import annotations

import time

import numpy as np

from drivers.camera.base import Frame
from service.calibrate.master import corrected
from service.measure.result import Measurement
from service.measure.turning import concentricity_check
from service.record import make_record
from service.runtime.calibration import CalibrationInUse
from service.runtime.compensating import CompensationService
from service.runtime.feed import MeasurementFeed, SequenceCounter
from service.runtime.modbus import ModbusFacade


class Publisher:
    """Publishes each measured frame (called by the pipeline, in frame order, on the loop).

    Parameters
    ----------
    sequence : SequenceCounter
        The measurements' sequence numbers.
    feed, modbus, compensation : MeasurementFeed, ModbusFacade, CompensationService
        Where the record goes.
    """

    def __init__(self, sequence: SequenceCounter, feed: MeasurementFeed,
                 modbus: ModbusFacade, compensation: CompensationService) -> None:
        self.sequence, self.feed = sequence, feed
        self.modbus, self.compensation = modbus, compensation
        modbus.set_sequence(sequence.current)

    def __call__(self, frame: Frame, raw: Measurement, in_use: CalibrationInUse) -> None:
        m = not_concentric(corrected(raw, in_use.correction), in_use)
        tracker = in_use.tracker
        if m and tracker is not None and m.free_center_mm and m.free_center_cov:
            xx, xy, yy = m.free_center_cov
            tracker.update(np.array(m.free_center_mm), np.array([[xx, xy], [xy, yy]]),
                           m.diameter_mm)
        comp = self.compensation
        record = make_record(
            seq=self.sequence.next(), wall_time=time.time(), frame_id=frame.frame_id,
            raw=raw, m=m, fused=self.feed.fused(m), feature=comp.feature(),
            part_temp_c=comp.part_temp_c, alpha_per_k=comp.alpha_per_k,
            latency_ms=(time.monotonic_ns() - frame.received_ns) / 1e6,
            calibration_id=in_use.info.id)
        self.modbus.publish(record)  # first: the latency is frame -> registers
        self.feed.publish(record, m, frame, in_use.geometry)
        comp.submit(record, frame.received_ns / 1e9)


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
