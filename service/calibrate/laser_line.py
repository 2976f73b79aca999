"""The laser line on a board photographed with the laser on and no laser-off twin (pure).

The board's pose comes from its pattern, which a laser line across it does not hide from the
detectors. The line is then the light above what the board's own pattern shows there: every
pixel of the board is mapped to the board's plane (the pose), the pattern's light is the
median of its kind of cell (a chessboard's square, the ground between a grid's circles) in
its neighbourhood, and what stands above it is the line. Cell edges, where the pattern's own
light changes within a pixel, are left out. In a colour image the line is looked for in the
channel where it stands out most against the others (a red laser: the red channel), less the
board as the other channels show it (a grey print reflects every colour alike, the laser
does not): the pattern's edges then cancel as in a twin's difference. The laser-off twin
stays the better way: its difference holds nothing but the line.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np

from service.calibrate.board import Board
from service.calibrate.intrinsics import charuco_print
from service.measure.stripe import StripeParams, extract_stripe

EDGE_CELLS = 0.12
"""Left out around a cell's edge (a circle's rim), in pitches: the blur of a transition."""
MIN_COLOUR_EXCESS = 12.0
"""A channel whose light stands this far (8-bit levels) above the others' ..."""
MIN_COLOUR_PIXELS = 100
"""... on this many pixels of the board holds a coloured line."""
_CHANNELS = ("blue", "green", "red")


@dataclass(frozen=True)
class LineOnBoard:
    """The laser line's centres on the board (px), and how it was found, in words."""

    points: np.ndarray
    how: str


def grey_of(image: np.ndarray) -> np.ndarray:
    """A grey copy of an image for the pattern detectors (OpenCV's weights for colour)."""
    if image.ndim == 2:
        return image
    code = cv2.COLOR_BGRA2GRAY if image.shape[2] == 4 else cv2.COLOR_BGR2GRAY
    return cv2.cvtColor(image, code)


def line_colour(image: np.ndarray, on_board: np.ndarray) -> int | None:
    """The channel (BGR index) a coloured line stands out in on the board, or None: the one
    above both others by ``MIN_COLOUR_EXCESS`` on the most pixels, at least
    ``MIN_COLOUR_PIXELS`` (a line is a small share of a board). The channels are balanced
    on the board's white first: a webcam's blue cast over the whole board is not a line."""
    if image.ndim == 2:
        return None
    bgr = image[..., :3].astype(np.float32) * np.float32(255.0 / _full_scale(image))
    if np.count_nonzero(on_board) >= MIN_COLOUR_PIXELS:
        white = np.percentile(bgr[on_board], 80, axis=0)  # the print's white, per channel
        bgr = bgr * (white.max() / np.maximum(white, 1.0)).astype(np.float32)
    counts = []
    for c in range(3):
        others = np.delete(bgr, c, axis=2).max(axis=2)
        counts.append(int(np.count_nonzero((bgr[..., c] - others)[on_board]
                                           > MIN_COLOUR_EXCESS)))
    best = int(np.argmax(counts))
    return best if counts[best] >= MIN_COLOUR_PIXELS else None


def pattern_image(image: np.ndarray, laser: int | None) -> np.ndarray:
    """A grey image of the board's pattern for its detector: in colour with a coloured line,
    the other two channels (the line hardly shows there); else grey."""
    if image.ndim == 2 or laser is None:
        return grey_of(image)
    others = np.delete(image[..., :3], laser, axis=2).astype(np.float32).mean(axis=2)
    return others.round().astype(image.dtype)


def _full_scale(image: np.ndarray) -> float:
    return 65535.0 if image.dtype == np.uint16 else 255.0


def board_coordinates(shape: tuple[int, int], box: tuple[int, int, int, int],
                      rvec: np.ndarray, tvec: np.ndarray, K: np.ndarray, dist: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray]:
    """Board-plane coordinates (mm, the board's frame) of every pixel in ``box`` (x0, y0,
    x1, y1): each pixel's undistorted ray met with the board's plane."""
    x0, y0, x1, y1 = box
    ys, xs = np.mgrid[y0:y1, x0:x1]
    px = np.column_stack([xs.ravel(), ys.ravel()]).astype(np.float64)
    rays = cv2.undistortPoints(px.reshape(-1, 1, 2), K, dist).reshape(-1, 2)
    R = cv2.Rodrigues(rvec)[0]
    t = np.asarray(tvec, float).ravel()
    d = np.column_stack([rays, np.ones(len(rays))])
    n = R[:, 2]
    s = (n @ t) / (d @ n)
    local = (d * s[:, None] - t) @ R  # R^T (X - t)
    h, w = y1 - y0, x1 - x0
    return local[:, 0].reshape(h, w), local[:, 1].reshape(h, w)


def pattern_extent(board: Board) -> tuple[float, float, float, float]:
    """The printed pattern without its margin, in pitches: a chessboard's squares, a ChArUco
    board's, a circle grid's circles with half a pitch around."""
    return replace(board, margin_squares=0.0 if board.kind in ("chess", "charuco")
                   else 0.5).extent()


def cells(board: Board, u_mm: np.ndarray, v_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each point's cell (an integer label, -1 off the printed pattern) and whether it lies
    clear of the cell's edges (``EDGE_CELLS``)."""
    u, v = u_mm / board.square_mm, v_mm / board.square_mm
    # The pattern itself, not the margin a print may or may not have: past a real board's
    # edge lies the bench, and its edge is a straight line as bright as the laser's.
    u0, u1, v0, v1 = pattern_extent(board)
    on = (u > u0) & (u < u1) & (v > v0) & (v < v1)
    if board.kind == "charuco":
        return _print_cells(board, u, v, on)
    if board.kind == "chess":
        fu, fv = np.floor(u), np.floor(v)
        in_checker = (u > -1) & (u < board.cols) & (v > -1) & (v < board.rows)
        # The margin is one cell of its own: white, its edge the checker's border.
        label = np.where(in_checker, (fv + 2) * (board.cols + 4) + (fu + 2), 0)
        du, dv = np.abs(u - np.round(u)), np.abs(v - np.round(v))
        clear = np.where(in_checker, (du > EDGE_CELLS) & (dv > EDGE_CELLS),
                         (np.abs(u - np.clip(u, -1, board.cols)) > EDGE_CELLS)
                         | (np.abs(v - np.clip(v, -1, board.rows)) > EDGE_CELLS))
    else:  # the nearest centre, as the simulator prints them
        cv = np.clip(np.round(v), 0, board.rows - 1)
        if board.kind == "circles":
            cu = np.clip(np.round(u), 0, board.cols - 1)
        else:
            shift = cv % 2
            cu = 2 * np.clip(np.round((u - shift) / 2), 0, board.cols - 1) + shift
        rim = np.hypot(u - cu, v - cv)
        # The ground between the circles is one cell a neighbourhood of pitches.
        label = (np.floor(v / 2) + 2) * (board.cols * 2 + 8) + np.floor(u / 2) + 2
        clear = np.abs(rim - board.dot_radius) > EDGE_CELLS
        label = np.where(rim < board.dot_radius, -2 - label, label)  # a circle: its own
    edge_u, edge_v = (u - u0 > EDGE_CELLS) & (u1 - u > EDGE_CELLS), \
        (v - v0 > EDGE_CELLS) & (v1 - v > EDGE_CELLS)
    return np.where(on, label, -1).astype(np.int64), clear & on & edge_u & edge_v


PRINT_TEXELS_PER_MM = 20.0
EDGE_PX = 2.5
"""Left out around a change of a print's ink, in image pixels."""


def _print_cells(board: Board, u: np.ndarray, v: np.ndarray, on: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """``cells`` of a printed pattern (a ChArUco board's squares and markers): a square's
    black and its white are two cells; clear where the print is one colour for
    ``EDGE_CELLS`` around."""
    tpm = PRINT_TEXELS_PER_MM
    ink = charuco_print(board, tpm) < 128
    # The markers' bits are a fraction of a square: what is left out around a change of ink
    # is the blur's reach in the image, EDGE_PX pixels on the board.
    mm_per_px = float(np.median(np.hypot(np.diff(u, axis=1), np.diff(v, axis=1)))) \
        * board.square_mm if u.shape[1] > 1 else 0.1
    reach = max(1, round(EDGE_PX * mm_per_px * tpm))
    kernel = np.ones((2 * reach + 1, 2 * reach + 1), np.uint8)
    plain = cv2.erode(ink.astype(np.uint8), kernel) | cv2.erode((~ink).astype(np.uint8), kernel)
    h, w = ink.shape
    tx = np.clip((u * board.square_mm * tpm).astype(int), 0, w - 1)
    ty = np.clip((v * board.square_mm * tpm).astype(int), 0, h - 1)
    inside = (u >= 0) & (u < board.cols) & (v >= 0) & (v < board.rows)
    square = (np.floor(v) + 2) * (board.cols + 4) + np.floor(u) + 2
    label = np.where(inside, 2 * square + ink[ty, tx], 0)
    clear = np.where(inside, plain[ty, tx] > 0,
                     (np.abs(u - np.clip(u, 0, board.cols)) > EDGE_CELLS)
                     | (np.abs(v - np.clip(v, 0, board.rows)) > EDGE_CELLS))
    u0, u1, v0, v1 = pattern_extent(board)
    edge = (u - u0 > EDGE_CELLS) & (u1 - u > EDGE_CELLS) & (v - v0 > EDGE_CELLS) \
        & (v1 - v > EDGE_CELLS)
    return np.where(on, label, -1).astype(np.int64), clear & on & edge


def line_without_twin(image: np.ndarray, board: Board, rvec: np.ndarray, tvec: np.ndarray,
                      K: np.ndarray, dist: np.ndarray, box: tuple[int, int, int, int]
                      ) -> LineOnBoard:
    """The laser line's centres on the board in a laser-on image (see the module
    docstring); ``box`` bounds the board in the image (x0, y0, x1, y1)."""
    x0, y0, x1, y1 = box
    u, v = board_coordinates(image.shape[:2], box, rvec, tvec, K, dist)
    label, clear = cells(board, u, v)
    crop = image[y0:y1, x0:x1]
    colour = line_colour(crop, label >= 0)
    if colour is not None:
        return _line_in_colour(crop, colour, label >= 0, (x0, y0), K, dist)
    how = "grey" if crop.ndim == 2 else "grey (no colour stands out on the board)"
    values = grey_of(crop).astype(np.float32)
    flat_label, flat_val, keep = label.ravel(), values.ravel(), clear.ravel()
    # The pattern's light a cell: the median of its clear pixels (a line covers a few).
    order = np.argsort(flat_label[keep], kind="stable")
    labs, vals = flat_label[keep][order], flat_val[keep][order]
    uniq, start = np.unique(labs, return_index=True)
    medians = np.array([np.median(part) for part in np.split(vals, start[1:])], np.float32)
    at = np.clip(np.searchsorted(uniq, flat_label), 0, max(len(uniq) - 1, 0))
    known = (len(uniq) > 0) & (uniq[at] == flat_label) if len(uniq) else \
        np.zeros(flat_label.shape, bool)
    model = np.where(known, medians[at] if len(uniq) else 0.0, np.nan
                     ).astype(np.float32).reshape(values.shape)
    usable = clear & np.isfinite(model)
    residual = np.where(usable, np.clip(values - np.nan_to_num(model), 0, None), 0)
    scale = 255.0 / _full_scale(image)
    stripe = extract_stripe((residual * scale).clip(0, 255).astype(np.uint8),
                            StripeParams(curvature_correction=False))
    # Away from where cells were left out: a gap's border is no line's side.
    return LineOnBoard(_kept(stripe.xy, usable, (x0, y0), K, dist),
                       f"{how}, above the board's own pattern")


def _kept(xy: np.ndarray, usable: np.ndarray, origin: tuple[int, int], K: np.ndarray,
          dist: np.ndarray) -> np.ndarray:
    """A crop's line centres (px of the image) a few pixels inside ``usable`` and on one
    straight line."""
    if not len(xy):
        return np.empty((0, 2))
    inner = cv2.erode(usable.astype(np.uint8), np.ones((7, 7), np.uint8)) > 0
    ix = np.clip(np.round(xy[:, 0]).astype(int), 0, inner.shape[1] - 1)
    iy = np.clip(np.round(xy[:, 1]).astype(int), 0, inner.shape[0] - 1)
    return on_one_line(xy[inner[iy, ix]] + list(origin), K, dist)


def _line_in_colour(crop: np.ndarray, colour: int, on_board: np.ndarray,
                    origin: tuple[int, int], K: np.ndarray, dist: np.ndarray) -> LineOnBoard:
    """The line in the channel it stands out in, less what the other channels show of the
    board there (a grey print reflects every colour alike: the laser channel's board is a
    linear function of the others', fitted on the board away from the line): the pattern's
    edges cancel as in a laser-off twin's difference."""
    bgr = crop[..., :3].astype(np.float32)
    line = bgr[..., colour]
    others = np.delete(bgr, colour, axis=2).mean(axis=2)
    away = on_board.copy()
    a, b = 1.0, 0.0
    for _ in range(3):  # the fit, then again without what stands above it (the line)
        x, y = others[away], line[away]
        if len(x) < 100:
            break
        a, b = np.polyfit(x, y, 1)
        rest = line - (a * others + b)
        away = on_board & (rest < np.percentile(rest[on_board], 95))
    residual = np.where(on_board, np.clip(line - (a * others + b), 0, None), 0)
    scale = 255.0 / _full_scale(crop)
    stripe = extract_stripe((residual * scale).clip(0, 255).astype(np.uint8),
                            StripeParams(curvature_correction=False))
    return LineOnBoard(_kept(stripe.xy, on_board, origin, K, dist),
                       f"the {_CHANNELS[colour]} channel less the board the others show")


def on_one_line(xy: np.ndarray, K: np.ndarray, dist: np.ndarray, tol_px: float = 2.0,
                tries: int = 300) -> np.ndarray:
    """The points that lie on one straight line once the lens's distortion is taken off
    (the light sheet meets the board's plane in a line), the most of them within ``tol_px``:
    what the pattern's own detail left above its level elsewhere is dropped."""
    if len(xy) < 10:
        return xy
    rays = cv2.undistortPoints(xy.reshape(-1, 1, 2).astype(np.float64), K, dist).reshape(-1, 2)
    tol = tol_px / float(K[0, 0])
    rng = np.random.default_rng(0)  # the same answer for the same images
    best = np.zeros(len(rays), bool)
    for _ in range(tries):
        i, j = rng.choice(len(rays), 2, replace=False)
        d = rays[j] - rays[i]
        norm = float(np.hypot(*d))
        if norm < 20 * tol:
            continue
        n = np.array([-d[1], d[0]]) / norm
        near = np.abs((rays - rays[i]) @ n) < tol
        if near.sum() > best.sum():
            best = near
    if best.sum() < 2:
        return xy
    # The line again through all of its points, and the points near it.
    c = rays[best].mean(axis=0)
    _, _, vt = np.linalg.svd(rays[best] - c)
    keep = np.abs((rays - c) @ vt[1]) < tol
    return xy[keep]
