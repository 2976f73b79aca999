"""Chessboard detections kept for the images a session's steps read again (in memory and, for
another process, on disk), and what a detection that found nothing says."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np

from drivers.sim.board_shots import Board, BoardRenderer
from drivers.sim.rig import RigConfig, ShaftRenderer
from service.calibrate import intrinsics, kept_detections
from service.calibrate.board import parse_board
from service.calibrate.kept_detections import detect_kept

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


def test_a_detection_kept_on_disk_is_read_by_another_process(tmp_path, monkeypatch) -> None:
    """A session's steps and the command line's run in processes of their own: what one
    detected, the next reads from the folder instead of detecting again; a file that cannot
    be read is detected again and written anew."""
    br = BoardRenderer(ShaftRenderer(RigConfig(), seed=0), BOARD)
    image, blank = br.render(br.pose_facing_camera(-10, 10, 400)), np.full((200, 300), 90,
                                                                           np.uint8)
    np.save(tmp_path / "image.npy", image)
    code = ("import numpy as np, sys; from pathlib import Path; "
            "from service.calibrate.kept_detections import detect_kept; "
            "from service.calibrate.board import Board; "
            "detect_kept([np.load(sys.argv[1])], Board(cols=11, rows=8, square_mm=8.0), "
            "Path(sys.argv[2]))")
    r = subprocess.run([sys.executable, "-c", code, str(tmp_path / "image.npy"),
                        str(tmp_path / "kept")], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    calls = []
    detect = intrinsics._detect_corners
    monkeypatch.setattr(intrinsics, "_detect_corners",
                        lambda im, board: calls.append(board) or detect(im, board))
    monkeypatch.setattr(intrinsics, "_kept", type(intrinsics._kept)())
    detect_kept([image], BOARD, tmp_path / "kept")
    assert calls == []
    assert np.array_equal(intrinsics.find_corners(image, BOARD).points,
                          detect(image, BOARD).points)
    assert calls == []
    # Nothing found is kept too, with what was seen; a damaged file is detected again.
    detect_kept([blank], BOARD, tmp_path / "kept")
    name = intrinsics.detection_name(blank, BOARD)
    kept = json.loads((tmp_path / "kept" / f"{name}.json").read_text())
    assert kept["points"] is None and "not found" in kept["reason"] and len(calls) == 1
    (tmp_path / "kept" / f"{name}.json").write_text('{"points": [[1, 2, 3]]')
    monkeypatch.setattr(intrinsics, "_kept", type(intrinsics._kept)())
    detect_kept([blank], BOARD, tmp_path / "kept")
    assert len(calls) == 2 and json.loads((tmp_path / "kept" / f"{name}.json").read_text()) \
        == kept
    # Another OpenCV, board or pixels: another name.
    assert len({name, intrinsics.detection_name(image, BOARD),
                intrinsics.detection_name(blank, Board(9, 6, 10.0))}) == 3


def test_a_charuco_detections_ids_are_kept(tmp_path, monkeypatch) -> None:
    board = parse_board("charuco:14x10x8x6")
    found = intrinsics.Corners(np.array([[1.5, 2.25], [3.0, 4.0]]), "", np.array([7, 9]))
    monkeypatch.setattr(kept_detections, "find_corners", lambda image, b: found)
    image = np.zeros((10, 10), np.uint8)
    kept_detections.detect_kept([image], board, tmp_path)
    monkeypatch.setattr(intrinsics, "_kept", type(intrinsics._kept)())
    monkeypatch.setattr(kept_detections, "find_corners", None)  # must not be called
    kept_detections.detect_kept([image], board, tmp_path)
    again = intrinsics.find_corners(image, board)
    assert np.array_equal(again.points, found.points) and np.array_equal(again.ids, found.ids)
