"""Quality verdicts and master corrections."""

from __future__ import annotations

import numpy as np
import pytest

from service.calibrate.axis import AxisResult
from service.calibrate.intrinsics import IntrinsicsResult
from service.calibrate.master import check_master, correction_from_masters
from service.calibrate.plane import PlaneResult
from service.calibrate.report import assess

K = np.eye(3)


def intr(rms=0.1, worst=0.5, coverage=0.7, used=12) -> IntrinsicsResult:
    return IntrinsicsResult(K, np.zeros(5), rms, [rms] * used, worst, coverage, 40.0,
                            list(range(used)))


def test_good_calibration() -> None:
    plane = PlaneResult(np.array([0.0, 0, 1]), 100.0, 0.01, 0.03, 2000, [500] * 4)
    axis = AxisResult(np.array([0.0, 0, 1]), np.zeros(3), 80.0, 0.005, 6)
    r = assess(intr(), plane, axis)
    assert r.verdict == "good" and r.reasons == []
    assert r.figures["plane_axis_angle_deg"] == pytest.approx(90.0)


@pytest.mark.parametrize(("kw", "verdict", "words"), [
    ({"rms": 0.5}, "marginal", "refocus"),
    ({"rms": 1.2}, "refused", "reprojection"),
    ({"coverage": 0.2}, "refused", "image corners"),
    ({"used": 7}, "marginal", "10-20 views"),
])
def test_verdicts_say_what_to_do(kw, verdict, words) -> None:
    r = assess(intr(**kw))
    assert r.verdict == verdict and any(words in x for x in r.reasons)


def test_a_failed_step_refuses() -> None:
    r = assess(intr(), PlaneResult(None, reason="turn the laser on"))
    assert r.verdict == "refused" and "turn the laser on" in r.reasons[0]


def test_plane_axis_angle_is_graded() -> None:
    plane = PlaneResult(np.array([0.0, 0, 1]), 100.0, 0.01, 0.03, 2000, [500] * 4)
    axis = AxisResult(np.array([1.0, 0, 0.2]) / np.hypot(1, 0.2), np.zeros(3), 80.0, 0.005, 6)
    r = assess(intr(), plane, axis)
    assert r.verdict == "refused" and "more squarely" in r.reasons[-1]


def test_masters() -> None:
    one = correction_from_masters([(30.000, 29.996)])
    assert one.apply(25.0) == pytest.approx(25.004)
    two = correction_from_masters([(20.000, 19.998), (40.000, 39.994)])
    assert two.apply(19.998) == pytest.approx(20.0) and two.apply(39.994) == pytest.approx(40.0)
    with pytest.raises(ValueError, match="differ"):
        correction_from_masters([(30.0, 29.9), (30.2, 30.1)])
    with pytest.raises(ValueError, match="scale"):
        correction_from_masters([(20.0, 20.0), (40.0, 41.0)])
    with pytest.raises(ValueError):
        correction_from_masters([])
    assert check_master(30.0, 30.002).passed and not check_master(30.0, 30.004).passed
