"""The rendered calibration board: corners where the camera model puts them."""

from __future__ import annotations

import cv2
import numpy as np

from drivers.sim.board_shots import Board, BoardRenderer
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


def _reference_sample(br: BoardRenderer, pose, rx: np.ndarray, ry: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray]:
    """One sample per ray in numpy: the ray met with the board plane, the checker (white
    margin) and the light sheet's Gaussian there."""
    n = pose.normal
    s = float(n @ pose.t) / (n[0] * rx + n[1] * ry + n[2])
    X = np.stack([rx * s, ry * s, s], axis=-1)
    local = (X - pose.t) @ pose.R
    u, v = local[..., 0] / br.board.square_mm, local[..., 1] / br.board.square_mm
    m, b = br.board.margin_squares, br.board
    inside = (u > -1 - m) & (u < b.cols + m) & (v > -1 - m) & (v < b.rows + m) & (s > 0)
    checker = (u > -1) & (u < b.cols) & (v > -1) & (v < b.rows)
    white = ~checker | ((np.floor(u) + np.floor(v)) % 2 == 0)
    refl = np.where(inside, np.where(white, 1.0, 0.12), 0.0)
    p = br._pose
    dist = X @ p.plane_normal - p.plane_d
    return refl, refl * np.exp(-0.5 * (dist / br.cfg.sheet_sigma_mm) ** 2)


def test_the_compiled_integration_is_the_mean_of_its_samples() -> None:
    """Each pixel's reflectance and laser light are the mean over its ``ss x ss`` samples of
    the board and the sheet evaluated directly; an edge is where those samples differ."""
    rig = ShaftRenderer(RigConfig(), seed=0)
    br = BoardRenderer(rig, BOARD)
    K = rig.config.camera_matrix()
    rays = rig._rays(1)[300:700:7, 400:1000:7]
    rx, ry = rays[..., 0], rays[..., 1]
    for pose in (br.pose_facing_camera(20, -10, 300), br.pose_on_spindle(30.0)):
        for ss in (3, 12):
            acc, lit, edge = br._integrate(pose, rx, ry, K, ss, laser=True)
            d = (np.arange(ss) + 0.5) / ss - 0.5
            samples = [_reference_sample(br, pose, rx + ox / K[0, 0], ry + oy / K[1, 1])
                       for ox in d for oy in d]
            refl = np.array([r for r, _ in samples])
            np.testing.assert_allclose(acc, refl.mean(axis=0), atol=1e-5)  # float32 sums
            np.testing.assert_allclose(lit, np.mean([li for _, li in samples], axis=0),
                                       atol=1e-5)
            np.testing.assert_array_equal(edge, refl.min(axis=0) != refl.max(axis=0))
            assert edge.any() and (~edge).any() and lit.max() > 0.1
