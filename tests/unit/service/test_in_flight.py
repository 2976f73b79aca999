"""A frame keeps the calibration it was taken under: activated meanwhile, a new calibration
neither lends it its correction nor lets compensation count it."""

from __future__ import annotations

import asyncio
from dataclasses import replace

import numpy as np

from drivers.camera.base import Frame
from service.calibrate.master import DiameterCorrection
from service.measure.result import Measurement, Method, Status
from service.serve import Children, build
from tests.unit.service.conftest import make_settings


def test_a_frame_in_flight_keeps_its_calibration(tmp_path) -> None:
    gauge, _ = build(make_settings(tmp_path), Children())
    old = gauge.in_use
    assert old is not None
    info, cal = gauge.calibration
    new_id = gauge.store.add(cal, by="test", note="second", activate=True)
    gauge.set_calibration(*gauge.store.get(new_id))
    gauge.set_correction(DiameterCorrection(0.005, 1.0, 0.0))  # the new calibration's
    gauge._comp_queue = asyncio.Queue(8)
    frame = Frame(np.zeros((4, 4), np.uint8), 1, 0, 0)
    m = Measurement(Status.OK, Method.AXIS, 30.0, uncertainty_mm=0.001)
    gauge._publish(frame, m, old)  # measured with the old geometry, published after the switch
    rec = gauge.latest
    assert rec.calibration_id == info.id != new_id
    assert rec.diameter_mm == rec.raw_diameter_mm == 30.0  # not the new calibration's correction
    queued = gauge._comp_queue.get_nowait()
    assert queued.calibration_id == info.id
    d = gauge.channel.controller.on_measurement(replace(queued, time_s=1.0), 1.0)
    assert d.code == "other_calibration", d
    gauge._publish(replace(frame, frame_id=2), m, gauge.in_use)
    assert gauge.latest.calibration_id == new_id and gauge.latest.diameter_mm == 30.005
