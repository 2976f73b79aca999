"""The region of interest follows the stripe: narrow, follow, widen on loss (time passed in)."""

from __future__ import annotations

import numpy as np

from service.runtime.roi import KEEP, RegionFollower

SENSOR = (1376, 1024)


def stripe(x0: float, y0: float, x1: float, y1: float, n: int = 400) -> np.ndarray:
    t = np.linspace(0.0, 1.0, n)
    return np.column_stack([x0 + (x1 - x0) * t, y0 + (y1 - y0) * t ** 2])


def test_a_whole_sensor_read_is_narrowed_to_the_stripe_and_its_margin() -> None:
    f = RegionFollower(SENSOR, margin_px=32)
    region = f.update(stripe(600, 300, 800, 700), None, 0.0)
    assert region == (568, 268, 800 + 33 - 568, 700 + 33 - 268)
    # Until the camera reads it, no new request (the frames in flight are whole).
    assert f.update(stripe(600, 300, 800, 700), None, 0.1) is KEEP


def test_the_region_holds_while_the_stripe_stays_inside_and_moves_with_it() -> None:
    f = RegionFollower(SENSOR, margin_px=32)
    region = f.update(stripe(600, 300, 800, 700), None, 0.0)
    assert f.update(stripe(602, 301, 801, 702), region, 0.5) is KEEP
    moved = f.update(stripe(640, 300, 840, 700), region, 1.0)  # 40 px to the right
    assert moved is not KEEP and moved[0] == 608
    # Changes that follow the stripe are at least min_interval_s apart.
    assert f.update(stripe(700, 300, 900, 700), moved, 1.1) is KEEP


def test_a_lost_stripe_widens_to_the_whole_sensor_and_is_found_again() -> None:
    f = RegionFollower(SENSOR, margin_px=32, lost_after=3)
    region = f.update(stripe(600, 300, 800, 700), None, 0.0)
    assert f.update(None, region, 0.5) is KEEP
    assert f.update(None, region, 0.6) is KEEP
    assert f.update(None, region, 0.7) is None            # the whole sensor again
    assert f.update(None, None, 0.8) is KEEP              # and it stays whole
    again = f.update(stripe(300, 200, 500, 600), None, 2.0)
    assert again is not KEEP and again[0] == 268


def test_a_stripe_that_fills_the_sensor_keeps_the_whole_sensor() -> None:
    f = RegionFollower(SENSOR, margin_px=32)
    assert f.update(stripe(10, 5, 1360, 1010), None, 0.0) is KEEP


def test_edges_of_the_sensor_are_not_edges_of_the_region() -> None:
    """A stripe running to the sensor's top edge does not make the region move."""
    f = RegionFollower(SENSOR, margin_px=32)
    region = f.update(stripe(600, 2, 800, 700), None, 0.0)
    assert region[1] == 0
    assert f.update(stripe(600, 1, 800, 700), region, 1.0) is KEEP
