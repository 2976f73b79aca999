"""The printed chessboard the calibration steps look for (the simulator renders the same
one): pure geometry, no I/O."""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

DEFAULT_BOARD = "11x8x8"


@dataclass(frozen=True)
class Board:
    """A printed chessboard."""

    cols: int = 9          # inner corners along x
    rows: int = 6          # inner corners along y
    square_mm: float = 6.0
    margin_squares: float = 1.0

    def object_points(self) -> np.ndarray:
        """Inner corners in the board frame, mm, OpenCV's order (row by row)."""
        xs, ys = np.meshgrid(np.arange(self.cols), np.arange(self.rows))
        pts = np.column_stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)])
        return pts * self.square_mm

    @property
    def size_mm(self) -> tuple[float, float]:
        """Outer size of the printed area, mm."""
        return ((self.cols + 1 + 2 * self.margin_squares) * self.square_mm,
                (self.rows + 1 + 2 * self.margin_squares) * self.square_mm)


def parse_board(text: str) -> Board:
    """``COLSxROWSxSQUARE_MM`` (inner corners, square size), e.g. ``11x8x8``.

    Raises
    ------
    ValueError
        Naming what to write instead.
    """
    m = re.fullmatch(r"(\d+)x(\d+)x(\d+(?:\.\d+)?)", text.strip())
    if not m:
        raise ValueError(f"--board {text!r}: write COLSxROWSxMM, e.g. 11x8x8 (inner corners)")
    cols, rows, sq = int(m[1]), int(m[2]), float(m[3])
    if cols < 3 or rows < 3 or sq <= 0:
        raise ValueError(f"--board {text!r}: at least 3x3 inner corners and a positive size")
    return Board(cols=cols, rows=rows, square_mm=sq)
