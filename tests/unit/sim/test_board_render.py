"""The rendered calibration board: corners where the camera model puts them."""

from __future__ import annotations

import cv2
import numpy as np

from drivers.sim.board import Board, BoardRenderer
from drivers.sim.rig import RigConfig, ShaftRenderer
from service.calibrate.intrinsics import find_corners

BOARD = Board(cols=11, rows=8, square_mm=8.0)


def test_detected_corners_match_the_projection_without_noise() -> None:
    """Each pixel integrates over its area, so a detector finds the corners where the pinhole
    model with distortion projects them: an error of 0.05 px per axis (what sampling each
    pixel 3x3 gave) would bias the focal length by 0.02 % and the axis point by 0.06 mm."""
    rig = ShaftRenderer(RigConfig(electrons_per_dn=1e9, read_noise_dn=0.0), seed=0)
    br = BoardRenderer(rig, BOARD)
    K, dist = rig.config.camera_matrix(), np.array(rig.config.dist_coeffs)
    obj = BOARD.object_points()
    errors = []
    for tx, ty, d, shift in [(25, 0, 400, (0, 0)), (0, -25, 380, (-20, -15)),
                             (-25, 25, 420, (20, 15)), (0, 0, 300, (0, 0))]:
        pose = br.pose_facing_camera(tx, ty, d, shift)
        found = find_corners(br.render(pose), BOARD).points
        assert found is not None
        truth = cv2.projectPoints(obj @ pose.R.T + pose.t, np.zeros(3), np.zeros(3), K,
                                  dist)[0].reshape(-1, 2)
        nearest = np.argmin(((truth[:, None] - found[None]) ** 2).sum(-1), axis=1)
        errors.append(found[nearest] - truth)
    e = np.concatenate(errors)
    assert np.abs(e.mean(axis=0)).max() < 0.02, e.mean(axis=0)
    assert e.std(axis=0).max() < 0.035, e.std(axis=0)
