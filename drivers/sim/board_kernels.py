"""The board renderer's inner loop, compiled (numba): each pixel's samples intersected with
the board plane, its checker and the light sheet looked up there, summed per pixel.

The same arithmetic as a numpy version over ``ss x ss`` offset copies of the ray arrays, but
one pass without the temporaries: a calibration session's 29 images in 8 s of a core
rather than 40 s (the tests render several sessions).
"""

from __future__ import annotations

import math

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def _on_circle(u: float, v: float, cols: float, rows: float, kind: int, dot: float) -> bool:
    """Whether (u, v), in pitches, lies on one of the grid's circles."""
    cv = min(max(math.floor(v + 0.5), 0.0), rows - 1)
    if kind == 1:
        cu = min(max(math.floor(u + 0.5), 0.0), cols - 1)
    else:  # row i's centres at 2 j + i mod 2
        shift = cv % 2
        cu = 2 * min(max(math.floor((u - shift) / 2 + 0.5), 0.0), cols - 1) + shift
    return (u - cu) ** 2 + (v - cv) ** 2 <= dot * dot


@numba.njit(cache=True, nogil=True)
def _charuco_white(x: float, y: float, sq: float, cols: float, rows: float, marker: float,
                   marks: np.ndarray, square_mark: np.ndarray) -> bool:
    """Whether the print is white at (x, y), in squares from its top-left corner: exact
    edges (the squares' and the markers' bits), no texture's grid."""
    if not (0 <= x < cols and 0 <= y < rows):
        return True  # the margin
    i, j = int(x), int(y)  # not negative here: the floor
    k = square_mark[j, i]
    if k < 0:
        return False
    off = (sq - marker) / 2
    lx, ly = (x - i) * sq - off, (y - j) * sq - off
    if not (0 <= lx < marker and 0 <= ly < marker):
        return True
    n = marks.shape[1]
    return marks[k, int(ly / marker * n), int(lx / marker * n)] >= 128


@numba.njit(cache=True, nogil=True)
def integrate_pixels(rx: np.ndarray, ry: np.ndarray, offsets: np.ndarray, R: np.ndarray,
                     t: np.ndarray, board: np.ndarray, sheet: np.ndarray, laser: bool,
                     marks: np.ndarray, square_mark: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean reflectance and laser light over pixels from their samples, and whether the
    samples of a pixel disagree (an edge runs through it).

    Parameters
    ----------
    rx, ry : ndarray, shape (N,)
        Normalised undistorted rays of the pixel centres.
    offsets : ndarray, shape (S, 2)
        Each sample's offset from the centre ray (already divided by the focal lengths).
    R, t : ndarray, shapes (3, 3) and (3,)
        The board's pose: ``X_cam = R X_board + t`` (mm).
    board : ndarray, shape (7,)
        ``square_mm, cols, rows, margin_squares, kind, dot_radius, marker_mm``: kind 0 a
        chessboard, 1 a symmetric circle grid, 2 an asymmetric one (``square_mm`` its pitch,
        the circles' radius ``dot_radius`` pitches), 3 a ChArUco board (``cols x rows``
        squares from the board's corner, its top-left one black, markers of ``marker_mm``).
    sheet : ndarray, shape (5,)
        The light plane's normal (3), its offset ``d`` (mm) and the sheet's sigma (mm).
    laser : bool
        Whether the laser is on.
    marks : ndarray of uint8, shape (K, n, n)
        Kind 3's markers, a cell a bit (their black border included; black below 128).
    square_mark : ndarray of int64, shape (rows, cols)
        Which marker each square of the print holds (-1: a black square), row 0 the print's
        top (the board's y = ``rows``).

    Returns
    -------
    acc, lit : ndarray of float32, shape (N,)
        Mean reflectance (1 white, 0.12 black, 0 off the board) and laser light.
    edge : ndarray of bool, shape (N,)
        The samples' reflectances differ.
    """
    n = rx.shape[0]
    acc = np.zeros(n, np.float32)
    lit = np.zeros(n, np.float32)
    edge = np.zeros(n, np.bool_)
    n0, n1, n2 = R[0, 2], R[1, 2], R[2, 2]
    nt = n0 * t[0] + n1 * t[1] + n2 * t[2]
    sq, cols, rows, m = board[0], board[1], board[2], board[3]
    kind, dot, marker = int(board[4]), board[5], board[6]
    count = np.float32(offsets.shape[0])
    for i in range(n):
        a = np.float32(0.0)
        li_sum = np.float32(0.0)
        lo, hi = np.inf, -np.inf
        for k in range(offsets.shape[0]):
            x = rx[i] + offsets[k, 0]
            y = ry[i] + offsets[k, 1]
            denom = n0 * x + n1 * y + n2
            r = 0.0
            li = 0.0
            if abs(denom) > 1e-9:
                s = nt / denom
                X0, X1, X2 = x * s - t[0], y * s - t[1], s - t[2]
                u = (X0 * R[0, 0] + X1 * R[1, 0] + X2 * R[2, 0]) / sq
                v = (X0 * R[0, 1] + X1 * R[1, 1] + X2 * R[2, 1]) / sq
                if kind == 0:
                    inside = -1 - m < u < cols + m and -1 - m < v < rows + m
                elif kind == 1:
                    inside = -m < u < cols - 1 + m and -m < v < rows - 1 + m
                elif kind == 3:
                    inside = -m < u < cols + m and -m < v < rows + m
                else:
                    inside = -m < u < 2 * cols - 1 + m and -m < v < rows - 1 + m
                if s > 0 and inside:
                    if kind == 0:
                        checker = -1 < u < cols and -1 < v < rows
                        white = (not checker) or (math.floor(u) + math.floor(v)) % 2 == 0
                    elif kind == 3:
                        # The board's y runs up the print: the print read the right way.
                        white = _charuco_white(u, rows - v, sq, cols, rows, marker, marks,
                                               square_mark)
                    else:
                        white = not _on_circle(u, v, cols, rows, kind, dot)
                    r = 1.0 if white else 0.12
                    if laser:
                        dist = (x * s * sheet[0] + y * s * sheet[1] + s * sheet[2]) - sheet[3]
                        li = r * math.exp(-0.5 * (dist / sheet[4]) ** 2)
            a += np.float32(r)
            li_sum += np.float32(li)
            lo = min(lo, r)
            hi = max(hi, r)
        acc[i] = a / count
        lit[i] = li_sum / count
        edge[i] = hi != lo
    return acc, lit, edge
