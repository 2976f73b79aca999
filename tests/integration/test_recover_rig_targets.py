"""Calibrating from a rendered circle grid and a ChArUco board recovers the simulated rig within
the chessboard's tolerances (tests/integration/test_recover_rig.py): the session's views,
laser pairs and spindle rotations; an asymmetric grid's centres are found where they are; a
ChArUco board partly out of view still counts."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.sim.board_shots import BoardRenderer, session_shots
from drivers.sim.rig import RigConfig, ShaftRenderer
from service.calibrate.axis import calibrate_axis
from service.calibrate.board import parse_board
from service.calibrate.intrinsics import calibrate_intrinsics, find_corners
from service.calibrate.kept_detections import detect_kept
from service.calibrate.plane import calibrate_plane
from service.measure.geometry import geometry_of
from tests.integration.test_recover_rig import deg, diameter_errors, in_rig_frame, off_axis_mm

TARGETS = ["circles:11x8x8", "charuco:14x10x8x6"]


@pytest.fixture(scope="module", params=TARGETS)
def recovered(request, detections):
    board = parse_board(request.param)
    rig = ShaftRenderer(RigConfig(), seed=3)
    br = BoardRenderer(rig, board)
    image = {s.name: br.render(s.pose(br), laser=s.laser, frame_index=s.frame_index)
             for s in session_shots()}
    # Its plane poses are test_plane_laser_on's too: detected once a run (kept_detections).
    detect_kept(list(image.values()), board, detections)
    kinds = {k: [image[s.name] for s in session_shots() if s.kind == k]
             for k in ("view", "plane_off", "plane_on", "axis")}
    pairs = list(zip(kinds["plane_off"], kinds["plane_on"], strict=True))
    intr = calibrate_intrinsics(kinds["view"] + kinds["plane_off"] + kinds["axis"], board)
    assert intr, intr.reason
    plane = calibrate_plane(pairs, board, intr.camera_matrix, intr.dist_coeffs)
    assert plane, plane.reason
    axis = calibrate_axis(kinds["axis"], board, intr.camera_matrix, intr.dist_coeffs,
                          (plane.normal, plane.d))
    assert axis, axis.reason
    return rig, board, intr, plane, axis


def test_intrinsics(recovered) -> None:
    rig, _, intr, _, _ = recovered
    K, Kt = intr.camera_matrix, rig.config.camera_matrix()
    assert abs(K[0, 0] / Kt[0, 0] - 1) < 0.002 and abs(K[1, 1] / Kt[1, 1] - 1) < 0.002
    assert abs(K[0, 2] - Kt[0, 2]) < 2.0 and abs(K[1, 2] - Kt[1, 2]) < 2.0
    assert intr.rms_px < 0.2 and intr.coverage > 0.5 and intr.tilt_spread_deg > 30
    assert len(intr.used) >= 20, intr.rejected


def test_light_plane_and_spindle_axis(recovered) -> None:
    rig, _, _, plane, axis = recovered
    geo = geometry_of(rig.calibration)
    assert deg(plane.normal, geo.plane_normal) < 0.05
    assert abs(plane.d - geo.plane_d) < 0.1 and plane.rms_mm < 0.05
    assert deg(axis.direction, geo.axis_direction) < 0.05
    truth = in_rig_frame(geo.plane_normal, geo.axis_direction, geo.axis_point)
    got = in_rig_frame(plane.normal, axis.direction, axis.point)
    assert np.linalg.norm(got - truth) < 0.05, got - truth
    assert off_axis_mm(axis.point, geo.axis_direction, geo.axis_point) < 0.05


def test_diameters_with_the_recovered_calibration(recovered) -> None:
    rig, _, intr, plane, axis = recovered
    errors = diameter_errors(rig, intr, plane, axis)
    assert np.mean(errors) < 0.015, errors


def test_an_asymmetric_grids_centres_are_found_where_they_are() -> None:
    """The asymmetric grid (its whole session as the symmetric one's, in ``make bench``'s
    time rather than the suite's): each centre within a fifth of a pixel of its circle's,
    tilted and on the spindle."""
    board = parse_board("acircles:5x7x9")
    br = BoardRenderer(ShaftRenderer(RigConfig(), seed=2), board)
    for pose in (br.pose_facing_camera(25, -25, 380), br.pose_on_spindle(30.0)):
        seen = find_corners(br.render(pose), board)
        assert seen.points is not None, seen.reason
        truth = br.project(pose, board.object_points())
        nearest = np.min(np.linalg.norm(seen.points[:, None] - truth[None], axis=-1), axis=1)
        assert nearest.max() < 0.2, nearest.max()


def test_a_charuco_board_partly_out_of_view_gives_the_corners_in_view() -> None:
    """Held near the image's corner, a third of the board out of the picture: the corners
    in view, named, where a chessboard or a grid is lost."""
    rig = ShaftRenderer(RigConfig(), seed=1)
    charuco = parse_board("charuco:12x9x7x5")
    br = BoardRenderer(rig, charuco)
    pose = br.pose_facing_camera(15, -10, 330, shift_mm=(-45.0, -30.0))
    seen = find_corners(br.render(pose), charuco)
    assert seen.points is not None and seen.ids is not None, seen.reason
    total = len(charuco.object_points())
    assert 0.3 * total < len(seen.ids) < 0.9 * total, len(seen.ids)
    truth = br.project(pose, seen.object_points(charuco))
    assert np.abs(seen.points - truth).max() < 0.5
    chess = BoardRenderer(rig, parse_board("11x7x7"))
    lost = find_corners(chess.render(chess.pose_facing_camera(15, -10, 330, (-45.0, -30.0))),
                        parse_board("11x7x7"))
    assert lost.points is None


@pytest.mark.parametrize("target", ["circles:11x8x8", "acircles:5x7x9"])
def test_a_grid_not_found_says_what_was_looked_for_and_seen(target: str) -> None:
    board = parse_board(target)
    blank = np.full((1024, 1376), 90, np.uint8)
    found = find_corners(blank, board)
    assert found.points is None and board.name in found.reason
    assert "0 dark and 0 light round blobs seen" in found.reason, found.reason
    chess = BoardRenderer(ShaftRenderer(RigConfig(), seed=1), parse_board("11x8x8"))
    wrong = find_corners(chess.render(chess.pose_facing_camera(10, 10, 400)), board)
    assert wrong.points is None and "wanted in a grid" in wrong.reason, wrong.reason
