"""A shoulder under the laser (service/measure/shoulder.py): two diameters in one frame are
refused, naming both; one surface, with its form, a run-out's arc or outliers, is not."""

from __future__ import annotations

import re

import numpy as np
import pytest

from drivers.sim.rig import RigConfig, ShaftRenderer
from service.measure.diameter import measure_frame
from service.measure.geometry import geometry_of
from service.measure.result import Method, Status
from service.measure.shoulder import second_diameter

ANGLES = np.radians(np.linspace(-70.0, 70.0, 400))


def named(why: str) -> list[float]:
    """The two diameters a refusal names, mm."""
    return sorted(float(x) for x in re.findall(r"(\d+\.\d{3}) ", why)[:2])


def arc(radius_mm: np.ndarray | float, angles: np.ndarray = ANGLES, sigma_mm: float = 0.002,
        seed: int = 0) -> np.ndarray:
    r = radius_mm + np.random.default_rng(seed).normal(0.0, sigma_mm, len(angles))
    return np.column_stack([r * np.cos(angles), r * np.sin(angles)])


@pytest.mark.parametrize("share", [0.15, 0.5, 0.8])
@pytest.mark.parametrize("other_mm", [14.5, 14.9, 15.3])
def test_two_diameters_along_the_arc_are_named(share: float, other_mm: float) -> None:
    radius = np.where(np.arange(len(ANGLES)) < share * len(ANGLES), other_mm, 15.0)
    why = second_diameter(arc(radius), np.zeros(2))
    assert "two diameters in one frame" in why
    assert named(why) == pytest.approx(sorted([2 * other_mm, 30.0]), abs=0.005), why


@pytest.mark.parametrize("surface", ["round", "lobed", "outliers", "sliver", "small step"])
def test_one_surface_is_not_a_shoulder(surface: str) -> None:
    rng = np.random.default_rng(3)
    radius = np.full(len(ANGLES), 15.0)
    if surface == "lobed":  # three lobes of 20 um: the form, not a step
        radius = radius + 0.020 * np.cos(3 * ANGLES)
    elif surface == "outliers":  # one point in ten off by up to 0.3 mm, here and there
        bad = rng.random(len(ANGLES)) < 0.1
        radius = radius + bad * rng.uniform(-0.3, 0.3, len(ANGLES))
    elif surface == "sliver":  # the stripe's end on a fillet: 5 % of the points
        radius = np.where(np.arange(len(ANGLES)) < 20, 14.6, radius)
    elif surface == "small step":  # 40 um of radius: below what is called a shoulder
        radius = np.where(np.arange(len(ANGLES)) < 200, 14.96, radius)
    assert second_diameter(arc(radius), np.zeros(2)) == ""


def test_a_rendered_shoulder_is_refused_and_one_diameter_measured() -> None:
    """Frames of a 30 mm and a 25 mm segment joined where the sheet crosses the shoulder:
    refused naming both; the 30 mm segment alone is measured."""
    rig = ShaftRenderer(RigConfig(), seed=1)
    geo = geometry_of(rig.calibration)
    big, small = rig.render(30.0, 3), rig.render(25.0, 3)
    rows = np.where(big.max(axis=1) > 60)[0]
    for share in (0.2, 0.5, 0.8):
        cut = int(rows.min() + share * (rows.max() - rows.min()))
        m = measure_frame(np.concatenate([big[:cut], small[cut:]]), geo, Method.AXIS)
        assert m.status is Status.UNCERTAIN and "two diameters in one frame" in m.reason, (
            share, m)
        assert named(m.reason) == pytest.approx([25.0, 30.0], abs=0.06), m.reason
    whole = measure_frame(big, geo, Method.AXIS)
    assert whole and abs(whole.diameter_mm - 30.0) < 0.01
