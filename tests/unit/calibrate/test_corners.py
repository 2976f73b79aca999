"""Chessboard detections kept for the images a session's steps read again, and what a
detection that found nothing says."""

from __future__ import annotations

import numpy as np

from drivers.sim.board_shots import Board, BoardRenderer
from drivers.sim.rig import RigConfig, ShaftRenderer
from service.calibrate import intrinsics
from service.calibrate.board import parse_board

BOARD = Board(cols=11, rows=8, square_mm=8.0)


def test_the_same_pixels_are_detected_once(monkeypatch) -> None:
    br = BoardRenderer(ShaftRenderer(RigConfig(), seed=0), BOARD)
    image = br.render(br.pose_facing_camera(10, -10, 380))
    calls = []
    detect = intrinsics._detect_corners
    monkeypatch.setattr(intrinsics, "_detect_corners",
                        lambda im, board: calls.append(board) or detect(im, board))
    monkeypatch.setattr(intrinsics, "_kept", type(intrinsics._kept)())
    first = intrinsics.find_corners(image, BOARD)
    assert first.points is not None and len(calls) == 1
    # A copy of the same pixels (the image read again from its file): from memory.
    again = intrinsics.find_corners(image.copy(), BOARD)
    assert again is first and len(calls) == 1
    with np.testing.assert_raises(ValueError):
        again.points[0, 0] = 0.0  # shared: nobody may change it
    # Other pixels, or another board, are detected.
    other = image.copy()
    other[0, 0] ^= 1
    intrinsics.find_corners(other, BOARD)
    assert intrinsics.find_corners(image, Board(9, 6, 10.0)).points is None
    assert len(calls) == 3


def test_the_kept_detections_are_bounded(monkeypatch) -> None:
    monkeypatch.setattr(intrinsics, "_kept", type(intrinsics._kept)())
    monkeypatch.setattr(intrinsics, "KEPT_DETECTIONS", 3)
    for k in range(5):
        intrinsics.find_corners(np.full((40, 60), k, np.uint8), BOARD)
    assert len(intrinsics._kept) == 3


def test_a_chessboard_not_found_says_what_to_check() -> None:
    """Which target was looked for, and what was seen: a blank image's missing contrast, or
    the two things a technician gets wrong (the board cut by the border, the corners
    miscounted)."""
    blank = intrinsics.find_corners(np.full((480, 640), 90, np.uint8), parse_board("13x12x30"))
    assert "chessboard of 13x12 inner corners not found" in blank.reason
    assert "little contrast (0 grey levels)" in blank.reason
    noise = np.random.default_rng(0).integers(0, 255, (480, 640)).astype(np.uint8)
    miss = intrinsics.find_corners(noise, parse_board("13x12x30"))
    assert "whole in the picture" in miss.reason and "13x12 its inner corners" in miss.reason
