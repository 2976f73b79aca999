"""The channel a laser line is looked for in: where the line is bright, not where the
camera's colour cast is (a webcam's green line on a bluish board was looked for in blue)."""

from __future__ import annotations

import numpy as np

from service.calibrate.laser_line import line_colour


def board_with_line(cast_bgr: tuple[float, float, float], line_bgr: tuple[int, int, int]
                    ) -> np.ndarray:
    """A 200 x 200 checkerboard (white 200, black 40) under a colour cast (gains per
    channel), a 3-px line of ``line_bgr`` across it."""
    y, x = np.mgrid[0:200, 0:200]
    grey = np.where(((x // 25) + (y // 25)) % 2 == 0, 200.0, 40.0)
    img = np.stack([grey * g for g in cast_bgr], axis=2)
    img[98:101, :, :] = line_bgr
    return np.clip(img, 0, 255).astype(np.uint8)


def test_a_green_line_on_a_bluish_board_is_found_in_green() -> None:
    img = board_with_line((1.15, 0.95, 0.9), (120, 255, 130))
    assert line_colour(img, np.ones(img.shape[:2], bool)) == 1


def test_a_neutral_board_keeps_its_line_colour_and_a_grey_line_none() -> None:
    assert line_colour(board_with_line((1, 1, 1), (60, 60, 250)),
                       np.ones((200, 200), bool)) == 2
    assert line_colour(board_with_line((1, 1, 1), (250, 250, 250)),
                       np.ones((200, 200), bool)) is None
