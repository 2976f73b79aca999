"""The fitted section drawn back onto the image runs through the stripe it was fitted to."""

from __future__ import annotations

import math

import cv2
import numpy as np

from drivers.sim.rig import RigConfig, ShaftRenderer
from service.measure.diameter import MeasureParams, measure_frame
from service.measure.geometry import geometry_of
from service.measure.overlay import SECTION_BGR, STRIPE_BGR, draw_overlay
from service.measure.result import Measurement, Method, Status
from service.measure.section import project_to_section, section_circle_on_plane


def test_section_circle_lies_on_the_plane_and_projects_back_to_the_circle() -> None:
    rig = ShaftRenderer(RigConfig(), seed=1)
    g = geometry_of(rig.calibration)
    pts = section_circle_on_plane((3.0, -2.0), 15.0, g.axis_direction, g.plane_normal,
                                  g.plane_d, n=90)
    assert pts.shape == (90, 3)
    assert np.allclose(pts @ g.plane_normal, g.plane_d)
    sec = project_to_section(pts, g.axis_direction)
    assert np.allclose(np.hypot(sec[:, 0] - 3.0, sec[:, 1] + 2.0), 15.0)


def test_overlay_section_passes_through_the_stripe_points() -> None:
    rig = ShaftRenderer(RigConfig(), seed=2)
    g = geometry_of(rig.calibration)
    image = rig.render(30.0, 0)
    m = measure_frame(image, g, Method.GEOMETRIC, MeasureParams(max_uncertainty_mm=math.inf))
    assert m, m.reason
    curve = section_circle_on_plane(m.center_mm, m.diameter_mm / 2, g.axis_direction,
                                    g.plane_normal, g.plane_d, n=3600)
    px, _ = cv2.projectPoints(curve, np.zeros(3), np.zeros(3), g.camera_matrix, g.dist_coeffs)
    px = px.reshape(-1, 2)
    gaps = [np.min(np.linalg.norm(px - p, axis=1)) for p in m.points_px[::10]]
    assert np.median(gaps) < 0.5 and max(gaps) < 2.0
    pic = draw_overlay(image, m, g, width=688)
    assert pic.shape == (512, 688, 3)
    red = np.all(pic == SECTION_BGR, axis=-1).sum()
    green = np.all(pic == STRIPE_BGR, axis=-1).sum()
    assert red > 100 and green > 50


def test_overlay_of_a_failed_frame_draws_no_section() -> None:
    image = np.full((1024, 1376), 5, np.uint8)
    m = Measurement.failed(Status.NO_STRIPE, Method.AXIS, "no stripe")
    pic = draw_overlay(image, m, None, width=344)
    assert pic.shape == (256, 344, 3)
    assert not np.all(pic == SECTION_BGR, axis=-1).any()
