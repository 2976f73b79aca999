"""A segment's frames fused into one measurement for its tool's law, against the weighted
mean worked by hand."""

from __future__ import annotations

import math

import pytest

from service.compensation.records import MeasurementIn
from service.compensation.segments import SegmentFusion


def frame(seq: int, t_s: float, d_mm: float, u_mm: float = 0.002) -> MeasurementIn:
    return MeasurementIn(seq, t_s, "ok", d_mm, u_mm, 7)


def test_a_segment_is_its_frames_weighted_mean_given_when_the_next_feature_comes() -> None:
    fusion: SegmentFusion[str] = SegmentFusion()
    assert fusion.add(frame(1, 0.0, 30.004, 0.002), "journal", 1) is None
    assert fusion.add(frame(2, 0.1, 30.001, 0.001), "journal", 1) is None
    ended = fusion.add(frame(3, 3.0, 26.000), "seat", 2)
    assert ended is not None
    m, feature = ended
    w1, w2 = 1 / 0.002 ** 2, 1 / 0.001 ** 2
    assert feature == "journal"
    assert m.diameter_mm == pytest.approx((w1 * 30.004 + w2 * 30.001) / (w1 + w2), abs=1e-12)
    assert m.uncertainty_mm == pytest.approx(1 / math.sqrt(w1 + w2))
    assert (m.seq, m.time_s, m.status, m.calibration_id) == (2, 0.1, "ok", 7)  # the last's


def test_a_pause_ends_a_segment_and_so_does_a_flush() -> None:
    fusion: SegmentFusion[int] = SegmentFusion(gap_s=10.0)
    fusion.add(frame(1, 0.0, 30.002), 1, 1)
    ended = fusion.add(frame(2, 10.5, 30.006), 1, 1)  # the same feature, the next part
    assert ended is not None and ended[0].diameter_mm == pytest.approx(30.002)
    flushed = fusion.flush()
    assert flushed is not None and flushed[0].diameter_mm == pytest.approx(30.006)
    assert fusion.flush() is None


def test_a_frame_without_a_diameter_is_refused() -> None:
    with pytest.raises(ValueError, match="diameter and an uncertainty"):
        SegmentFusion().add(MeasurementIn(1, 0.0, "ok", None, None), 1, 1)
