"""The calibration targets the steps look for (the simulator renders the same ones): pure
geometry, no I/O.

A target is described once, as text that the CLI, the wizard, the API and the calibration
documents all use:

- ``chess:COLSxROWSxMM``, or plain ``COLSxROWSxMM``: a chessboard of ``COLS x ROWS`` inner
  corners, squares of ``MM``;
- ``circles:COLSxROWSxPITCH_MM``: a symmetric grid of ``COLS x ROWS`` circles, centres
  ``PITCH_MM`` apart;
- ``acircles:COLSxROWSxPITCH_MM``: an asymmetric grid in OpenCV's convention (``COLS``
  circles a row, every other row shifted by half a period; centre ``j`` of row ``i`` at
  ``((2 j + i mod 2) PITCH, i PITCH)``).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

DEFAULT_BOARD = "11x8x8"

KINDS = ("chess", "circles", "acircles")
_NAMES = {"chess": "chessboard", "circles": "symmetric circle grid",
          "acircles": "asymmetric circle grid"}


@dataclass(frozen=True)
class Board:
    """A printed target (see the module docstring)."""

    cols: int = 9          # inner corners (chess) or circles along x
    rows: int = 6          # ... along y
    square_mm: float = 6.0  # the square's side (chess) or the circles' pitch
    margin_squares: float = 1.0
    kind: str = "chess"
    detector: str = "sb"
    """How a chessboard's corners are found: ``sb`` OpenCV's sector-based detector (its
    accuracy mode), ``sb+subpix`` then refined by ``cornerSubPix`` (the intrinsics step
    keeps the one that fits its images better, and the later steps use it)."""

    def object_points(self) -> np.ndarray:
        """Its points in the board frame, mm, in the order OpenCV's detector gives them (row
        by row)."""
        xs, ys = np.meshgrid(np.arange(self.cols), np.arange(self.rows))
        if self.kind == "acircles":
            xs = 2 * xs + ys % 2
        pts = np.column_stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)])
        return pts * self.square_mm

    @property
    def dot_radius(self) -> float:
        """A circle's radius in pitches (the simulator's print; a detector does not need it)."""
        return 0.25

    def extent(self) -> tuple[float, float, float, float]:
        """The printed area in pitches of the board frame: (u0, u1, v0, v1), margin
        included."""
        m = self.margin_squares
        if self.kind == "chess":
            return -1.0 - m, self.cols + m, -1.0 - m, self.rows + m
        last = self.cols - 1 if self.kind == "circles" else 2 * (self.cols - 1) + 1
        return -m, last + m, -m, self.rows - 1 + m

    @property
    def size_mm(self) -> tuple[float, float]:
        """Outer size of the printed area, mm."""
        u0, u1, v0, v1 = self.extent()
        return (u1 - u0) * self.square_mm, (v1 - v0) * self.square_mm

    def describe(self) -> str:
        """Its description (``parse_board`` reads it back)."""
        return f"{self.kind}:{self.cols}x{self.rows}x{self.square_mm:g}"

    @property
    def name(self) -> str:
        """In words, for a reason or a report: ``symmetric circle grid of 7x7``."""
        what = "inner corners" if self.kind == "chess" else "circles"
        return f"{_NAMES[self.kind]} of {self.cols}x{self.rows} {what}"


def parse_board(text: str) -> Board:
    """A board from its description (see the module docstring), e.g. ``11x8x8``,
    ``circles:7x7x37.5``.

    Raises
    ------
    ValueError
        Naming what to write instead.
    """
    kind, _, dims = text.strip().rpartition(":")
    kind = kind or "chess"
    if kind not in KINDS:
        raise ValueError(f"--board {text!r}: the target is one of {', '.join(KINDS)} "
                         "(e.g. circles:7x7x37.5)")
    m = re.fullmatch(r"(\d+)x(\d+)x(\d+(?:\.\d+)?)", dims)
    if not m:
        unit = "inner corners, square mm" if kind == "chess" else "circles, pitch mm"
        raise ValueError(f"--board {text!r}: write {kind}:COLSxROWSxMM ({unit}), e.g. "
                         f"{'11x8x8' if kind == 'chess' else kind + ':7x7x37.5'}")
    cols, rows, sq = int(m[1]), int(m[2]), float(m[3])
    least = 3 if kind == "chess" else 2
    if cols < least or rows < least or sq <= 0:
        raise ValueError(f"--board {text!r}: at least {least}x{least} "
                         f"{'inner corners' if kind == 'chess' else 'circles'} and a positive "
                         "size")
    if kind == "acircles" and rows < 3:
        raise ValueError(f"--board {text!r}: an asymmetric grid needs 3 rows or more")
    return Board(cols=cols, rows=rows, square_mm=sq, kind=kind)


def board_of(doc: object) -> Board:
    """A board as a calibration document keeps it: its description, or ``[cols, rows, mm]``
    (a chessboard: documents written before the description)."""
    if isinstance(doc, str):
        return parse_board(doc)
    cols, rows, sq = doc  # type: ignore[misc]
    return Board(cols=int(cols), rows=int(rows), square_mm=float(sq))
