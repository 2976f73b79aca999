"""The targets' one description (service/calibrate/board.py): each form read and written
back, a bad one refused naming what to write, documents of the release before read as they
were."""

from __future__ import annotations

import numpy as np
import pytest

from service.calibrate.board import Board, board_of, parse_board


@pytest.mark.parametrize(("text", "kind", "points"), [
    ("11x8x8", "chess", 88), ("chess:11x8x8", "chess", 88), ("circles:7x7x37.5", "circles", 49),
    ("acircles:4x11x20", "acircles", 44), ("charuco:12x9x8x6", "charuco", 88),
    ("charuco:5x7x30x22:DICT_4X4_50", "charuco", 24)])
def test_each_form_is_read_and_written_back(text: str, kind: str, points: int) -> None:
    board = parse_board(text)
    assert board.kind == kind and len(board.object_points()) == points
    assert parse_board(board.describe()) == board


def test_object_points_follow_opencvs_conventions() -> None:
    acircles = parse_board("acircles:4x11x20").object_points()
    assert np.allclose(acircles[:5, :2], [[0, 0], [40, 0], [80, 0], [120, 0], [20, 20]])
    charuco = parse_board("charuco:12x9x8x6").object_points()
    assert np.allclose(charuco[:2, :2], [[8, 8], [16, 8]]) and np.allclose(charuco[11], [8, 16, 0])
    assert parse_board("charuco:12x9x8x6").dictionary == "DICT_5X5_100"


@pytest.mark.parametrize(("text", "says"), [
    ("hexagons:7x7x5", "one of chess, circles, acircles, charuco"),
    ("circles:7x7", "circles:COLSxROWSxMM"),
    ("11x8", "COLSxROWSxMM"),
    ("2x8x8", "at least 3x3 inner corners"),
    ("acircles:4x2x20", "3 rows or more"),
    ("charuco:12x9x8", "charuco:COLSxROWSxSQUARE_MMxMARKER_MM"),
    ("charuco:12x9x8x9", "markers smaller than the squares"),
    ("charuco:12x9x8x6:DICT_9X9_7", "not one of OpenCV's ArUco dictionaries"),
    # The second outside probe: a board no camera at a lathe resolves took gigabytes or
    # hours, or graded an absurd calibration good; a square of 400 digits is infinite.
    ("charuco:1000000x1000000x8x6", "at most 60 squares a side"),
    ("charuco:1400x1000x8x6", "at most 60 squares a side"),
    ("charuco:16x14x8x6", "hold 112 markers, more than DICT_5X5_100's 100"),
    ("11x8x0.0001", "the square must be 0.5 to 200 mm"),
    ("circles:11x8x900", "the pitch must be 0.5 to 200 mm"),
    ("11x8x" + "9" * 60, "the square must be 0.5 to 200 mm, not 1e"),
    ("11x8x" + "9" * 400, "a description of at most 80 characters")])
def test_a_bad_description_says_what_to_write(text: str, says: str) -> None:
    with pytest.raises(ValueError, match=says):
        parse_board(text)


def test_documents_of_the_release_before_keep_their_chessboard() -> None:
    assert board_of([11, 8, 8.0]) == Board(11, 8, 8.0)
    assert board_of("circles:7x7x37.5").kind == "circles"
