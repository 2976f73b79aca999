"""The simulated rig: a valid exact calibration, deterministic frames, turning speckle."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drivers.sim.rig import RigConfig, ShaftRenderer, rig_calibration
from service.measure.geometry import geometry_of


def test_calibration_is_valid_and_matches_the_config() -> None:
    cfg = RigConfig(triangulation_deg=40.0)
    cal = rig_calibration(cfg)
    geo = geometry_of(cal)
    assert geo.camera_matrix[0, 0] == pytest.approx(25.0 / 6.45e-3)
    assert geo.image_size == (1376, 1024)
    # The light plane makes the triangulation angle with the camera's viewing direction, up to
    # the small misalignment of the camera.
    view = math.degrees(math.asin(abs(geo.plane_normal[2])))
    assert view == pytest.approx(40.0, abs=2.5)
    # The axis point lies on the light plane and about standoff_mm in front of the camera.
    assert geo.plane_normal @ geo.axis_point == pytest.approx(geo.plane_d, abs=1e-9)
    assert np.linalg.norm(geo.axis_point) == pytest.approx(300.0, rel=1e-9)


def test_frames_are_deterministic_and_speckle_changes_between_frames() -> None:
    a = ShaftRenderer(RigConfig(), seed=3)
    b = ShaftRenderer(RigConfig(), seed=3)
    f0, f0b, f1 = a.render(25.0, 0), b.render(25.0, 0), a.render(25.0, 1)
    assert f0.dtype == np.uint8 and f0.shape == (1024, 1376)
    assert np.array_equal(f0, f0b)
    assert not np.array_equal(f0, f1)


def test_the_stripe_moves_with_the_diameter(renderer) -> None:
    def stripe_centroid(img: np.ndarray) -> np.ndarray:
        ys, xs = np.nonzero(img > 60)
        return np.array([xs.mean(), ys.mean()])

    c20, c40 = stripe_centroid(renderer.render(20.0)), stripe_centroid(renderer.render(40.0))
    assert np.linalg.norm(c40 - c20) > 20


def test_laser_azimuth_sets_the_visible_arc() -> None:
    from service.measure.diameter import measure_frame

    arcs = []
    for az in (40.0, 75.0):
        r = ShaftRenderer(RigConfig(laser_azimuth_deg=az), seed=1)
        m = measure_frame(r.render(30.0), geometry_of(r.calibration))
        assert m, m.reason
        arcs.append(m.arc_deg)
    assert arcs[0] > arcs[1] + 20


def test_the_stripes_light_is_the_frames_without_its_noise() -> None:
    """``stripe_light``: the speckled light of frame i is what the frame holds over its
    ambient light, but for the sensor's noise and 8 bits; without a frame, the clean
    light of ``render_clean``."""
    r = ShaftRenderer(RigConfig(), seed=3)
    light, (x0, y0) = r.stripe_light(25.0, 2)
    h, w = light.shape
    frame = r.render(25.0, 2).astype(np.float64)[y0:y0 + h, x0:x0 + w]
    ambient = r._ambient(25.0)[y0:y0 + h, x0:x0 + w]
    bright = light > 50
    left = (frame - ambient - light)[bright]
    # The sensor's shot and read noise (another frame's speckle would leave ~19 DN here).
    noise = np.sqrt(np.mean((light + ambient)[bright]) / 8.0 + 1.2**2)
    assert abs(left.mean()) < 0.5 and np.std(left) < 1.3 * noise, (left.mean(), np.std(left))
    clean, _ = r.stripe_light(25.0)
    assert np.array_equal(clean, r.render_clean(25.0)[y0:y0 + h, x0:x0 + w])
    assert not np.array_equal(light, clean)


def test_the_speckle_floor_weighs_each_centre_by_its_own_scatter() -> None:
    """``speckle_floor.floor_um`` on shifts of known, uneven variance: the scatter of the
    inverse-variance mean, sum(1 / v)^-1/2, not that of the plain mean."""
    from tests.bench.speckle_floor import floor_um

    rng = np.random.default_rng(1)
    sd = np.linspace(1.0, 6.0, 200)
    shifts = rng.normal(0.0, 1.0, (400, 200)) * sd
    best = 2.0 / np.sqrt(np.sum(1.0 / sd**2))
    assert np.std(floor_um(shifts)) == pytest.approx(best, rel=0.1)
    assert np.std(2.0 * shifts.mean(axis=1)) > 1.5 * best
