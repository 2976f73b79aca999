"""Calibrating from rendered images recovers the simulated rig (issue 6's tolerances)."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from calib_store.model import SCHEMA, parse_calibration
from drivers.sim.board_shots import Board, BoardRenderer, session_shots
from drivers.sim.rig import RigConfig, ShaftRenderer
from service.calibrate.axis import calibrate_axis
from service.calibrate.intrinsics import calibrate_intrinsics
from service.calibrate.kept_detections import detect_kept
from service.calibrate.plane import calibrate_plane
from service.measure.diameter import MeasureParams, measure_frame
from service.measure.geometry import geometry_of
from service.measure.result import Method

BOARD = Board(cols=11, rows=8, square_mm=8.0)


def deg(a: np.ndarray, b: np.ndarray) -> float:
    return math.degrees(math.acos(min(1.0, abs(float(a @ b)))))


@pytest.fixture(scope="module")
def session(calibration_images):
    """The session ``shaftgauge calibrate render`` writes (rendered once a run for every
    test that reads it: a minute of rendering on its own otherwise), and its rig."""
    rig = ShaftRenderer(RigConfig(), seed=3)  # the frames measured with what is recovered
    br = BoardRenderer(rig, BOARD)
    folder = {"view": "views", "plane_off": "plane", "plane_on": "plane", "axis": "axis"}
    image = {s.name: cv2.imread(str(calibration_images / folder[s.kind] / f"{s.name}.png"),
                                cv2.IMREAD_GRAYSCALE) for s in session_shots()}
    assert all(im is not None for im in image.values()), calibration_images
    kinds = {k: [image[s.name] for s in session_shots() if s.kind == k]
             for k in ("view", "plane_off", "plane_on", "axis")}
    views, spindle = kinds["view"], kinds["axis"]
    pairs = list(zip(kinds["plane_off"], kinds["plane_on"], strict=True))
    return rig, br, views, pairs, spindle


@pytest.fixture(scope="module")
def recovered(session, detections):
    _, _, views, pairs, spindle = session
    # What the run's other tests detected in these images already (kept_detections).
    detect_kept(views + [im for pair in pairs for im in pair] + spindle, BOARD, detections)
    # Every board image of the session constrains the intrinsics, as in the service's session.
    intr = calibrate_intrinsics(views + [off for off, _ in pairs] + spindle, BOARD)
    assert intr, intr.reason
    plane = calibrate_plane(pairs, BOARD, intr.camera_matrix, intr.dist_coeffs)
    assert plane, plane.reason
    axis = calibrate_axis(spindle, BOARD, intr.camera_matrix, intr.dist_coeffs,
                          (plane.normal, plane.d))
    assert axis, axis.reason
    return intr, plane, axis


def test_intrinsics(session, recovered) -> None:
    rig, *_ = session
    intr, _, _ = recovered
    K, Kt = intr.camera_matrix, rig.config.camera_matrix()
    assert abs(K[0, 0] / Kt[0, 0] - 1) < 0.002 and abs(K[1, 1] / Kt[1, 1] - 1) < 0.002
    assert abs(K[0, 2] - Kt[0, 2]) < 2.0 and abs(K[1, 2] - Kt[1, 2]) < 2.0
    assert intr.rms_px < 0.2 and intr.coverage > 0.5 and intr.tilt_spread_deg > 30


def test_light_plane(session, recovered) -> None:
    rig, *_ = session
    _, plane, _ = recovered
    geo = geometry_of(rig.calibration)
    assert deg(plane.normal, geo.plane_normal) < 0.05
    assert abs(plane.d - geo.plane_d) < 0.1 and plane.rms_mm < 0.05


def test_spindle_axis_direction(session, recovered) -> None:
    rig, *_ = session
    _, _, axis = recovered
    geo = geometry_of(rig.calibration)
    assert deg(axis.direction, geo.axis_direction) < 0.05


def off_axis_mm(point: np.ndarray, direction: np.ndarray, line_point: np.ndarray) -> float:
    """Distance of ``point`` from the line through ``line_point`` along ``direction``: a point
    given for the axis is right when it lies on the axis, wherever along it."""
    a = direction / np.linalg.norm(direction)
    v = point - line_point
    return float(np.linalg.norm(v - (v @ a) * a))


def in_rig_frame(normal: np.ndarray, direction: np.ndarray, point: np.ndarray) -> np.ndarray:
    """The axis line's position across itself, in a frame of the camera centre, the axis and
    the light plane's normal: unchanged by a rotation of the whole camera frame."""
    a = direction / np.linalg.norm(direction)
    b = normal - (normal @ a) * a
    b /= np.linalg.norm(b)
    return np.array([point @ b, point @ np.cross(a, b)])


def test_spindle_axis_position_relative_to_the_rig(session, recovered) -> None:
    """Where the axis runs relative to the camera centre and the light plane: what the
    measurement uses (a rotation of the whole camera frame does not show here)."""
    rig, *_ = session
    _, plane, axis = recovered
    geo = geometry_of(rig.calibration)
    truth = in_rig_frame(geo.plane_normal, geo.axis_direction, geo.axis_point)
    got = in_rig_frame(plane.normal, axis.direction, axis.point)
    assert np.linalg.norm(got - truth) < 0.05, got - truth


def test_spindle_axis_point_in_the_camera_frame(session, recovered) -> None:
    """Issue 6's 0.05 mm, in the camera frame itself (where the principal point's error
    turns the whole frame: on this session 0.044 mm, seeds 4 and 5 0.034 and 0.028)."""
    rig, *_ = session
    _, _, axis = recovered
    geo = geometry_of(rig.calibration)
    assert off_axis_mm(axis.point, geo.axis_direction, geo.axis_point) < 0.05


def diameter_errors(rig: ShaftRenderer, intr, plane, axis) -> list[float]:
    """How far shafts of four diameters are measured off with a recovered calibration, mm
    (the free circle's own accuracy, never refused as uncertain: this tests the
    calibration)."""
    a = axis.direction / np.linalg.norm(axis.direction)
    cal = geometry_of(parse_calibration({
        "schema": SCHEMA, "units": "mm", "image_size": list(rig.config.image_size),
        "camera_matrix": intr.camera_matrix.tolist(),
        "dist_coeffs": [float(x) for x in intr.dist_coeffs],
        "light_plane": {"normal": [float(x) for x in plane.normal], "d": float(plane.d)},
        "axis": {"direction": [float(x) for x in a], "point": [float(x) for x in axis.point]},
    }))
    errors = []
    for i, d in enumerate((20.113, 29.8, 39.76, 47.062)):
        m = measure_frame(rig.render(d, i), cal, Method.GEOMETRIC,
                          MeasureParams(max_uncertainty_mm=math.inf))
        assert m, m.reason
        errors.append(abs(m.diameter_mm - d))
    return errors


def test_diameters_with_the_recovered_calibration(session, recovered) -> None:
    rig, *_ = session
    errors = diameter_errors(rig, *recovered)
    assert np.mean(errors) < 0.015, errors


def test_bad_sessions_are_refused_saying_what_to_do(session) -> None:
    rig, br, views, pairs, spindle = session
    few = calibrate_intrinsics(views[:3], BOARD)
    assert not few and "need 6" in few.reason and "more views" in few.reason
    blank = [np.full((1024, 1376), 40, np.uint8)] * 8
    none_found = calibrate_intrinsics(blank, BOARD)
    assert not none_found and "found in 0 of 8" in none_found.reason
    assert all("not found" in why for why in none_found.rejected.values())
    flat = [br.render(br.pose_facing_camera(0, 0, d, (dx, dy)), frame_index=500 + i)
            for i, (d, dx, dy) in enumerate([(380, 0, 0), (400, -15, 10), (420, 15, -10),
                                             (390, -10, -10), (410, 10, 10), (400, 0, 12)])]
    untilted = calibrate_intrinsics(flat, BOARD)
    assert not untilted and "never tilted" in untilted.reason and "tilt it" in untilted.reason
    K, dist = rig.config.camera_matrix(), np.array(rig.config.dist_coeffs)
    dark = calibrate_plane([(b, b) for b, _ in pairs], BOARD, K, dist)
    assert not dark and "turn the laser on" in dark.reason
    assert all("laser line missing" in why for why in dark.rejected.values())
    narrow = calibrate_axis(spindle[2:4], BOARD, K, dist)
    assert not narrow and "need 3" in narrow.reason

