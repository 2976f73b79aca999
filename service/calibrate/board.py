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
  ``((2 j + i mod 2) PITCH, i PITCH)``);
- ``charuco:COLSxROWSxSQUARE_MMxMARKER_MM[:DICTIONARY]``: a ChArUco board of ``COLS x ROWS``
  squares (OpenCV's ``CharucoBoard``, its top-left square black), ArUco markers of
  ``MARKER_MM`` in its white squares from ``DICTIONARY`` (OpenCV's name, ``DICT_5X5_100`` when
  not given). Its points are the inner corners, each named by its markers: a board partly out
  of view still gives those in view.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np

DEFAULT_BOARD = "11x8x8"

KINDS = ("chess", "circles", "acircles", "charuco")
_NAMES = {"chess": "chessboard", "circles": "symmetric circle grid",
          "acircles": "asymmetric circle grid", "charuco": "ChArUco board"}
DEFAULT_DICTIONARY = "DICT_5X5_100"
MAX_A_SIDE = 60
"""The most corners, circles or squares a side: a printed or certified board a camera at a
lathe resolves has a few dozen (the simulated session's 11x8, a large ChArUco 14x10); each
point is searched for and refined, so a board of thousands a side would take hours."""
SIZE_MM = (0.5, 200.0)
"""A square's or a pitch's size, mm: what a camera 100-1000 mm from the board resolves (a
board of 0.1 um squares put the axis 4 um from the camera and was graded good)."""


@dataclass(frozen=True)
class Board:
    """A printed target (see the module docstring)."""

    cols: int = 9          # inner corners (chess) or circles along x
    rows: int = 6          # ... along y
    square_mm: float = 6.0  # the square's side (chess) or the circles' pitch
    margin_squares: float = 1.0
    kind: str = "chess"
    marker_mm: float = 0.0  # a ChArUco board's markers
    dictionary: str = ""    # ... and their dictionary (OpenCV's name)
    detector: str = "sb"
    """How a chessboard's corners are found: ``sb`` OpenCV's sector-based detector (its
    accuracy mode), ``sb+subpix`` then refined by ``cornerSubPix`` (the intrinsics step
    keeps the one that fits its images better, and the later steps use it)."""

    def object_points(self) -> np.ndarray:
        """Its points in the board frame, mm, in the order OpenCV's detector gives them (row
        by row)."""
        if self.kind == "charuco":  # inner corners, id by id; the board's corner the origin
            xs, ys = np.meshgrid(np.arange(1, self.cols), np.arange(1, self.rows))
        else:
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
        if self.kind == "charuco":
            return -m, self.cols + m, -m, self.rows + m
        last = self.cols - 1 if self.kind == "circles" else 2 * (self.cols - 1) + 1
        return -m, last + m, -m, self.rows - 1 + m

    @property
    def size_mm(self) -> tuple[float, float]:
        """Outer size of the printed area, mm."""
        u0, u1, v0, v1 = self.extent()
        return (u1 - u0) * self.square_mm, (v1 - v0) * self.square_mm

    def describe(self) -> str:
        """Its description (``parse_board`` reads it back)."""
        text = f"{self.kind}:{self.cols}x{self.rows}x{self.square_mm:g}"
        if self.kind == "charuco":
            text += f"x{self.marker_mm:g}:{self.dictionary}"
        return text

    @property
    def name(self) -> str:
        """In words, for a reason or a report: ``symmetric circle grid of 7x7 circles``."""
        what = {"chess": "inner corners", "charuco": "squares"}.get(self.kind, "circles")
        text = f"{_NAMES[self.kind]} of {self.cols}x{self.rows} {what}"
        return text + (f" ({self.dictionary})" if self.kind == "charuco" else "")


def parse_board(text: str) -> Board:
    """A board from its description (see the module docstring), e.g. ``11x8x8``,
    ``circles:7x7x37.5``.

    Raises
    ------
    ValueError
        Naming what to write instead.
    """
    if len(text) > 80:
        raise ValueError(f"--board: a description of at most 80 characters, not {len(text)}")
    if text.strip().startswith("charuco:"):
        return _parse_charuco(text)
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
    what = "inner corners" if kind == "chess" else "circles"
    if cols < least or rows < least:
        raise ValueError(f"--board {text!r}: at least {least}x{least} {what}")
    _check_size(text, cols, rows, what, **{"square" if kind == "chess" else "pitch": sq})
    if kind == "acircles" and rows < 3:
        raise ValueError(f"--board {text!r}: an asymmetric grid needs 3 rows or more")
    return Board(cols=cols, rows=rows, square_mm=sq, kind=kind)


def _parse_charuco(text: str) -> Board:
    _, _, rest = text.strip().partition(":")
    dims, _, dictionary = rest.partition(":")
    dictionary = dictionary or DEFAULT_DICTIONARY
    m = re.fullmatch(r"(\d+)x(\d+)x(\d+(?:\.\d+)?)x(\d+(?:\.\d+)?)", dims)
    if not m:
        raise ValueError(f"--board {text!r}: write charuco:COLSxROWSxSQUARE_MMxMARKER_MM"
                         f"[:DICTIONARY] (squares), e.g. charuco:12x9x8x6:{DEFAULT_DICTIONARY}")
    cols, rows, sq, marker = int(m[1]), int(m[2]), float(m[3]), float(m[4])
    if cols < 3 or rows < 3 or not 0 < marker < sq:
        raise ValueError(f"--board {text!r}: at least 3x3 squares, markers smaller than the "
                         "squares")
    _check_size(text, cols, rows, "squares", square=sq, marker=marker)
    if not re.fullmatch(r"DICT_(\dX\d_(50|100|250|1000)|ARUCO_ORIGINAL|APRILTAG_\w+)",
                        dictionary):
        raise ValueError(f"--board {text!r}: {dictionary!r} is not one of OpenCV's ArUco "
                         f"dictionaries (e.g. {DEFAULT_DICTIONARY}, DICT_4X4_50, DICT_6X6_250)")
    size = re.search(r"_(50|100|250|1000)$", dictionary)
    markers = cols * rows // 2
    if size and markers > int(size[1]):
        raise ValueError(f"--board {text!r}: {cols}x{rows} squares hold {markers} markers, "
                         f"more than {dictionary}'s {size[1]}")
    return Board(cols=cols, rows=rows, square_mm=sq, kind="charuco", marker_mm=marker,
                 dictionary=dictionary)


def _check_size(text: str, cols: int, rows: int, what: str, **sizes_mm: float) -> None:
    """ValueError unless the board is one a camera at a lathe could use (``MAX_A_SIDE``,
    ``SIZE_MM``)."""
    if cols > MAX_A_SIDE or rows > MAX_A_SIDE:
        raise ValueError(f"--board {text!r}: at most {MAX_A_SIDE} {what} a side, not "
                         f"{cols}x{rows}")
    lo, hi = SIZE_MM
    for name, mm in sizes_mm.items():
        if not (math.isfinite(mm) and lo <= mm <= hi):
            raise ValueError(f"--board {text!r}: the {name} must be {lo:g} to {hi:g} mm, "
                             f"not {mm:.6g}")


def board_of(doc: object) -> Board:
    """A board as a calibration document keeps it: its description, or ``[cols, rows, mm]``
    (a chessboard: documents written before the description)."""
    if isinstance(doc, str):
        return parse_board(doc)
    cols, rows, sq = doc  # type: ignore[misc]
    return Board(cols=int(cols), rows=int(rows), square_mm=float(sq))
