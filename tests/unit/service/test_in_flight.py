"""A frame keeps the calibration it was taken under: activated meanwhile, a new calibration
neither lends it its correction nor lets compensation count it."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from drivers.camera.base import Frame
from service.calibrate.master import DiameterCorrection
from service.compensation import MeasurementIn
from service.measure.result import Measurement, Method, Status
from service.serve import Children, build
from tests.unit.service.conftest import make_settings


def test_a_frame_in_flight_keeps_its_calibration(tmp_path) -> None:
    gauge, _ = build(make_settings(tmp_path), Children())
    ctx, comp, publish = gauge.context, gauge.compensation, gauge.pipeline.on_result
    old = ctx.in_use
    assert old is not None
    info, cal = ctx.calibration
    new_id = ctx.store.add(cal, by="test", note="second", activate=True)
    ctx.set_calibration(*ctx.store.get(new_id))
    ctx.set_correction(DiameterCorrection(0.005, 1.0, 0.0))  # the new calibration's
    queue: list[MeasurementIn] = []
    comp.submit = lambda record, received_s, held=None, feature=None: queue.append(  # given
        MeasurementIn(record.seq, received_s, record.status, record.diameter_mm,
                      record.uncertainty_mm, record.calibration_id))
    frame = Frame(np.zeros((4, 4), np.uint8), 1, 0, 0)
    m = Measurement(Status.OK, Method.AXIS, 30.0, uncertainty_mm=0.001)
    publish(frame, m, old)  # measured with the old geometry, published after the switch
    rec = gauge.feed.latest
    assert rec.calibration_id == info.id != new_id
    assert rec.diameter_mm == rec.raw_diameter_mm == 30.0  # not the new calibration's correction
    assert queue[0].calibration_id == info.id
    d = comp.in_force()[0][1].controller.on_measurement(replace(queue[0], time_s=1.0), 1.0)
    assert d.code == "other_calibration", d
    publish(replace(frame, frame_id=2), m, ctx.in_use)
    assert gauge.feed.latest.calibration_id == new_id and gauge.feed.latest.diameter_mm == 30.005
