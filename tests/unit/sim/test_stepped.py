"""The stepped shaft a simulated camera shows: segments in turn, each tool's wear, a part's
scatter shared by the frames of a segment."""

from __future__ import annotations

import pytest

from drivers.sim.stepped import Segment, SteppedPart

PART = SteppedPart((Segment(30.0, 1), Segment(26.0, 1), Segment(34.0, 2, 0.004)),
                   dwell_s=2.0, wear_um_per_min=((1, 0.6), (2, 1.2)), insert_every_min=10.0,
                   part_sigma_mm=0.0015, seed=4)


def test_the_segments_in_turn_with_their_tools_wear() -> None:
    flat = SteppedPart(PART.segments, 2.0, PART.wear_um_per_min, 10.0, part_sigma_mm=0.0)
    assert flat.at(0.5) == pytest.approx(30.0 + 0.0006 * 0.5 / 60)
    assert flat.at(2.5) == pytest.approx(26.0 + 0.0006 * 2.5 / 60)
    assert flat.at(5.0) == pytest.approx(34.004 + 0.0012 * 5.0 / 60)  # its deflection
    assert flat.at(6.5) == pytest.approx(30.0 + 0.0006 * 6.5 / 60)  # the next part
    assert flat.at(600.5) == pytest.approx(30.0 + 0.0006 * 0.5 / 60)  # a new insert


def test_a_parts_scatter_is_one_draw_a_segment() -> None:
    assert PART.at(0.1) - PART.at(1.9) == pytest.approx(-0.0006 * 1.8 / 60)
    still = SteppedPart(PART.segments, 2.0, ((1, 0.0), (2, 0.0)), part_sigma_mm=0.0015)
    draws = [still.at(0.5 + 6.0 * k) - 30.0 for k in range(200)]
    mean = sum(draws) / len(draws)
    sd = (sum((d - mean) ** 2 for d in draws) / (len(draws) - 1)) ** 0.5
    assert 0.0012 < sd < 0.0018


def test_a_bad_spec_is_refused_naming_it() -> None:
    with pytest.raises(ValueError, match="no wear rate for tools"):
        SteppedPart((Segment(30.0, 3),))
    with pytest.raises(ValueError, match="not a stepped part"):
        SteppedPart.from_json('{"segments": [{"diameter": 30}]}')
    part = SteppedPart.from_json('{"segments": [{"diameter_mm": 30, "tool": 2}], '
                                 '"wear_um_per_min": {"2": 0.5}, "part_sigma_mm": 0}')
    assert part.at(60.0) == pytest.approx(30.0005)


def test_each_tools_setup_and_wear_offset_move_only_its_own_segments() -> None:
    part = SteppedPart.from_json('{"segments": [{"diameter_mm": 30, "tool": 1}, '
                                 '{"diameter_mm": 34, "tool": 2}], "dwell_s": 2, '
                                 '"wear_um_per_min": {"1": 0, "2": 0}, "part_sigma_mm": 0, '
                                 '"setup_mm": {"2": -0.012}}')
    assert part.tools == [1, 2]
    assert part.at(1.0) == pytest.approx(30.0) and part.at(3.0) == pytest.approx(33.988)
    cut = {1: -0.005, 2: 0.010}
    assert part.at(1.0, cut) == pytest.approx(29.995)
    assert part.at(3.0, cut) == pytest.approx(33.998)
    assert [part.part_at(t) for t in (0.0, 3.9, 4.0, 9.0)] == [0, 0, 1, 2]
