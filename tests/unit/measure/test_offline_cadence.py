"""The offline ``measure`` looks at its images for a reflection as the service looks at its
frames: at the service's cadence for the frame rate given, every image while one is seen,
and every image when asked."""

from __future__ import annotations

import pytest

from calib_store.model import load_calibration
from drivers.sim.disturb import Disturbances, Ghost
from drivers.sim.frames import write_frames
from drivers.sim.rig import RigConfig
from service import offline
from service.measure import diameter
from service.measure.result import Method


def checked(monkeypatch) -> list[int]:
    """Count the images the reflection model is asked about (a lopsided stripe is asked by
    the measurement itself, whatever the cadence: none here)."""
    calls: list[int] = []
    real = diameter.fit_reflection
    monkeypatch.setattr(diameter, "fit_reflection",
                        lambda *a, **kw: calls.append(1) or real(*a, **kw))
    return calls


@pytest.mark.parametrize(("fps", "hz", "expected"), [(10.0, 5.0, 3), (10.0, 2.5, 2),
                                                      (10.0, float("inf"), 6), (2.0, 5.0, 6),
                                                      (10.0, 0.0, 0)])
def test_clean_images_are_checked_at_the_services_cadence(tmp_path, monkeypatch, fps, hz,
                                                           expected) -> None:
    paths = write_frames(tmp_path, [30.0], count=6, seed=2)
    cal = load_calibration(tmp_path / "calibration.json")
    calls = checked(monkeypatch)
    results = list(offline.measure_images([str(p) for p in paths], cal, Method.AXIS, fps=fps,
                                          reflection_check_hz=hz))
    assert all(m for _, m in results)
    assert len(calls) == expected


def test_once_a_reflection_is_seen_every_image_is_checked(tmp_path, monkeypatch) -> None:
    faint = RigConfig(disturbances=Disturbances(ghost=Ghost(gain=0.1, offset_px=(2.0, 0.0),
                                                            blur_px=1.5)))
    paths = write_frames(tmp_path, [30.0], count=6, seed=2, config=faint)
    cal = load_calibration(tmp_path / "calibration.json")
    calls = checked(monkeypatch)
    results = list(offline.measure_images([str(p) for p in paths], cal, Method.AXIS))
    assert results[0][1].reflection_px is not None, results[0][1]
    assert len(calls) == 6
    assert all(m.reflection_px is not None for _, m in results)
