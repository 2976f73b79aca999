"""Camera intrinsics from images of a target (Zhang's method, OpenCV): chessboards and
circle grids (``service.calibrate.board``)."""

from __future__ import annotations

import functools
import hashlib
import math
import threading
from collections import OrderedDict
from dataclasses import dataclass, field

import cv2
import numpy as np

from service.calibrate.board import Board

_SUBPIX = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 50, 1e-4)
SUBPIX_HALF_WINDOW = 5
"""``cornerSubPix``'s half window (11 x 11 px, as Bouguet's corner finder)."""


@dataclass(frozen=True)
class Corners:
    """The target's points in one image, px (N, 2), or None when it was not found; ``ids``
    the indices of ``Board.object_points`` they are (None: all of them, in order)."""

    points: np.ndarray | None
    reason: str = ""
    ids: np.ndarray | None = None

    def object_points(self, board: Board) -> np.ndarray:
        """The board-frame points these are, mm (N, 3)."""
        obj = board.object_points()
        return obj if self.ids is None else obj[self.ids]


MIN_CHARUCO_CORNERS = 8
"""A ChArUco board partly in view counts with this many inner corners or more."""


KEPT_DETECTIONS = 128
"""Detections kept by ``find_corners`` (a few kB each): a calibration's steps read the same
images again (the intrinsics every board image, the plane its laser-off images, the axis its
spindle rotations), and a step run again after one more capture reads them all. Steps in
processes of their own keep them on disk too (``service.calibrate.kept_detections``)."""

_kept: OrderedDict[tuple, Corners] = OrderedDict()
_kept_lock = threading.Lock()


def find_corners(image: np.ndarray, board: Board) -> Corners:
    """The target's points in a grey image, in ``board.object_points`` order: a chessboard's
    sub-pixel inner corners, a circle grid's centres.

    The detector takes about half a second an image; a detection of the same pixels (their
    digest) and board is given again from memory (the last ``KEPT_DETECTIONS``)."""
    pixels = np.ascontiguousarray(image)
    key = _key(pixels, board)
    with _kept_lock:
        found = _kept.get(key)
        if found is not None:
            _kept.move_to_end(key)
            return found
    found = _detect_corners(pixels, board)
    _remember(key, found)
    return found


def _key(pixels: np.ndarray, board: Board) -> tuple:
    return (pixels.shape, pixels.dtype.str, hashlib.blake2b(pixels.data, digest_size=16)
            .digest(), board)


def detection_name(image: np.ndarray, board: Board) -> str:
    """A name for the detection of these pixels and board by this OpenCV, the same in every
    process (for keeping it outside one: ``service.calibrate.kept_detections``)."""
    key = _key(np.ascontiguousarray(image), board)
    return hashlib.blake2b(repr((*key, cv2.__version__)).encode(), digest_size=16).hexdigest()


def keep_detection(image: np.ndarray, board: Board, found: Corners) -> None:
    """Give ``found`` for these pixels and board from now on, as if ``find_corners`` had
    detected it here (a detection kept by another process)."""
    _remember(_key(np.ascontiguousarray(image), board), found)


def _remember(key: tuple, found: Corners) -> None:
    if found.points is not None:
        found.points.flags.writeable = False
    with _kept_lock:
        _kept[key] = found
        while len(_kept) > KEPT_DETECTIONS:
            _kept.popitem(last=False)


def _detect_corners(image: np.ndarray, board: Board) -> Corners:
    if board.kind == "charuco":
        return _detect_charuco(image, board)
    if board.kind != "chess":
        return _detect_circles(image, board)
    size = (board.cols, board.rows)
    missing = Corners(None, f"{board.name} not found: {_what_was_seen(image, board)}")
    try:
        ok, corners = cv2.findChessboardCornersSB(image, size, flags=cv2.CALIB_CB_ACCURACY)
        if ok and corners is not None and board.detector == "sb+subpix":
            w = SUBPIX_HALF_WINDOW
            corners = cv2.cornerSubPix(_subpix_source(image), corners.astype(np.float32),
                                       (w, w), (-1, -1), _SUBPIX)
        if not ok or corners is None:
            ok, corners = cv2.findChessboardCorners(image, size,
                                                    flags=cv2.CALIB_CB_ADAPTIVE_THRESH)
            if not ok:
                return missing
            corners = cv2.cornerSubPix(image, corners, (5, 5), (-1, -1), _SUBPIX)
    except cv2.error:  # an image too small or odd for OpenCV's detectors holds no board
        return missing
    return Corners(corners.reshape(-1, 2).astype(np.float64))


def aruco_board(board: Board) -> cv2.aruco.CharucoBoard:
    """OpenCV's ChArUco board for a description."""
    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, board.dictionary))
    return cv2.aruco.CharucoBoard((board.cols, board.rows), board.square_mm, board.marker_mm,
                                  dictionary)


@functools.lru_cache(maxsize=4)
def charuco_print(board: Board, texels_per_mm: float) -> np.ndarray:
    """A ChArUco board's print, ``texels_per_mm`` a mm, its top-left corner the board's
    origin (uint8: 0 black, 255 white; not to be written to)."""
    size = (round(board.cols * board.square_mm * texels_per_mm),
            round(board.rows * board.square_mm * texels_per_mm))
    image = np.ascontiguousarray(aruco_board(board).generateImage(size, marginSize=0))
    image.flags.writeable = False
    return image


def _detect_charuco(image: np.ndarray, board: Board) -> Corners:
    """A ChArUco board's inner corners in view, each by its id (a board partly out of the
    picture gives the corners it shows)."""
    grey = image if image.dtype == np.uint8 else cv2.convertScaleAbs(image, alpha=1 / 257)
    try:
        detector = cv2.aruco.CharucoDetector(aruco_board(board))
        corners, ids, _, markers = detector.detectBoard(grey)
    except (cv2.error, AttributeError) as err:
        return Corners(None, f"{board.name} not found: {err}")
    seen = 0 if markers is None else len(markers)
    found = 0 if ids is None else len(ids)
    if found < MIN_CHARUCO_CORNERS:
        return Corners(None, f"{board.name} not found: {seen} of its markers seen, "
                             f"{found} inner corners (need {MIN_CHARUCO_CORNERS})")
    order = np.argsort(ids.ravel())
    return Corners(corners.reshape(-1, 2)[order].astype(np.float64), "",
                   ids.ravel()[order].astype(np.int64))


def _subpix_source(image: np.ndarray) -> np.ndarray:
    """``cornerSubPix`` takes 8-bit or float images."""
    return image if image.dtype == np.uint8 else image.astype(np.float32)


def _what_was_seen(image: np.ndarray, board: Board) -> str:
    """For a chessboard not found: how little contrast the image has, or what to check."""
    grey = image if image.dtype == np.uint8 else cv2.convertScaleAbs(image, alpha=1 / 257)
    low, high = np.percentile(grey, [2, 98])
    if high - low < 30:
        return f"the image has little contrast ({high - low:.0f} grey levels): light the board"
    return (f"is it whole in the picture, and are {board.cols}x{board.rows} its inner corners "
            "(squares less one, each way)?")


def _blob_detector(image: np.ndarray, board: Board, dark: bool) -> cv2.SimpleBlobDetector:
    """Blobs from a few pixels up to a share of the image a circle of the grid can have
    (OpenCV's defaults stop at 5000 px: a grid filling a 1920x1080 image has larger dots);
    round enough for a circle seen at a tilt."""
    p = cv2.SimpleBlobDetector_Params()
    p.blobColor = 0 if dark else 255
    p.minArea = 12.0
    p.maxArea = float(image.shape[0] * image.shape[1]) / (board.cols * board.rows)
    p.filterByCircularity = True
    p.minCircularity = 0.5
    p.filterByInertia = True
    p.minInertiaRatio = 0.1
    p.filterByConvexity = True
    p.minConvexity = 0.8
    p.minDistBetweenBlobs = 2.0
    return cv2.SimpleBlobDetector_create(p)


def _detect_circles(image: np.ndarray, board: Board) -> Corners:
    """A circle grid's centres: dark circles on a light ground, or light on dark."""
    grey = image if image.dtype == np.uint8 else cv2.convertScaleAbs(image, alpha=1 / 257)
    flags = cv2.CALIB_CB_SYMMETRIC_GRID if board.kind == "circles" \
        else cv2.CALIB_CB_ASYMMETRIC_GRID
    size = (board.cols, board.rows)
    seen = []
    try:
        for dark in (True, False):
            detector = _blob_detector(grey, board, dark)
            ok, centres = cv2.findCirclesGrid(grey, size, flags=flags, blobDetector=detector)
            if ok and centres is not None:
                return Corners(_refined(grey, centres.reshape(-1, 2).astype(np.float64),
                                        dark))
            seen.append(len(detector.detect(grey)))
    except cv2.error:
        seen = seen or [0]
    return Corners(None, f"{board.name} not found: {seen[0]} dark and "
                         f"{seen[-1] if len(seen) > 1 else 0} light round blobs seen, "
                         f"{board.cols * board.rows} wanted in a grid")


def _refined(image: np.ndarray, centres: np.ndarray, dark: bool, rounds: int = 3
             ) -> np.ndarray:
    """Each circle's centre as the centroid of its darkness (lightness) beyond a quarter of
    the way from its local ground to its core, in a window of twice its radius at most (and
    half way to its nearest neighbour), moved with the centroid a few times. The blob
    detector's centres come from thresholded contours, tenths of a pixel off on a blurred,
    tilted circle; above the threshold the ground's noise weighs nothing, so a window the
    image's border cuts does not pull the centre."""
    d = np.linalg.norm(centres[:, None] - centres[None], axis=-1)
    np.fill_diagonal(d, np.inf)
    img = image.astype(np.float64)
    h, w = img.shape
    out = centres.copy()
    for k, reach in enumerate(0.45 * d.min(axis=1)):
        c, r = out[k], reach
        for _ in range(rounds):
            x0, x1 = int(max(0, np.floor(c[0] - r))), int(min(w, np.ceil(c[0] + r) + 1))
            y0, y1 = int(max(0, np.floor(c[1] - r))), int(min(h, np.ceil(c[1] + r) + 1))
            if x1 - x0 < 3 or y1 - y0 < 3:
                break
            ys, xs = np.mgrid[y0:y1, x0:x1]
            inside = (xs - c[0]) ** 2 + (ys - c[1]) ** 2 <= r * r
            patch = img[y0:y1, x0:x1][inside]
            signal = -patch if dark else patch
            ground, core = np.percentile(signal, 10), np.percentile(signal, 99)
            wgt = np.clip(signal - (ground + 0.25 * (core - ground)), 0.0, None)
            if not wgt.sum() > 0:
                break
            c = np.array([(xs[inside] * wgt).sum(), (ys[inside] * wgt).sum()]) / wgt.sum()
            r = min(reach, 2.0 * np.sqrt(np.count_nonzero(wgt) / np.pi) + 2.0)
        out[k] = c
    return out


@dataclass(frozen=True)
class IntrinsicsResult:
    """Camera matrix and distortion, with per-image figures, or why there are none."""

    camera_matrix: np.ndarray | None
    dist_coeffs: np.ndarray | None
    rms_px: float = math.nan
    per_image_rms_px: list[float] = field(default_factory=list)
    worst_px: float = math.nan
    coverage: float = 0.0          # fraction of the image area the corners' hull covered
    tilt_spread_deg: float = 0.0   # largest angle between two board normals
    used: list[int] = field(default_factory=list)
    rejected: dict[int, str] = field(default_factory=dict)
    reason: str = ""
    detector: str = "sb"           # the corners' detector it kept (``Board.detector``)

    def __bool__(self) -> bool:
        return self.camera_matrix is not None and not self.reason


def calibrate_intrinsics(images: list[np.ndarray], board: Board, min_images: int = 6,
                         min_tilt_deg: float = 15.0) -> IntrinsicsResult:
    """Intrinsics (k1, k2, p1, p2; k3 fixed at 0) from images of the target.

    Refuses (a falsy result whose reason says what to do): too few images with a board found,
    boards never tilted (all normals within ``min_tilt_deg``: the focal length is then not
    observable).
    """
    if not images:
        return IntrinsicsResult(None, None, reason="no images: capture 10-20 views of the board")
    h, w = images[0].shape[:2]
    obj, img, used, rejected = [], [], [], {}
    for i, im in enumerate(images):
        if im.shape[:2] != (h, w):
            rejected[i] = f"image is {im.shape[1]}x{im.shape[0]}, the others {w}x{h}"
            continue
        c = find_corners(im, board)
        if c.points is None:
            rejected[i] = c.reason
            continue
        obj.append(c.object_points(board).astype(np.float32))
        img.append(c.points.astype(np.float32))
        used.append(i)
    if len(used) < min_images:
        return IntrinsicsResult(None, None, used=used, rejected=rejected, reason=(
            f"the board was found in {len(used)} of {len(images)} images, need {min_images}: "
            f"capture more views with the whole {board.name.split(' of ')[0]} in the "
            "picture"))
    flags = cv2.CALIB_FIX_K3
    rms, K, dist, rvecs, tvecs = cv2.calibrateCamera(obj, img, (w, h), None, None, flags=flags)
    detector = board.detector
    if board.kind == "chess" and board.detector == "sb":
        # A chessboard's corners refined by cornerSubPix fit real photographs better (a
        # published set: rms 0.18 px against 0.22, and its published result), the detector's
        # own fit rendered boards better (0.05 px against 0.08): the images decide.
        hw = SUBPIX_HALF_WINDOW
        refined = [cv2.cornerSubPix(_subpix_source(images[i]), p.copy(), (hw, hw), (-1, -1),
                                    _SUBPIX) for i, p in zip(used, img, strict=True)]
        other = cv2.calibrateCamera(obj, refined, (w, h), None, None, flags=flags)
        if other[0] < rms:
            rms, K, dist, rvecs, tvecs = other
            img, detector = refined, "sb+subpix"
    normals = [cv2.Rodrigues(r)[0][:, 2] for r in rvecs]
    spread = max(math.degrees(math.acos(min(1.0, abs(float(a @ b)))))
                 for a in normals for b in normals)
    per_image, worst = [], 0.0
    for o, p, r, t in zip(obj, img, rvecs, tvecs, strict=True):
        proj, _ = cv2.projectPoints(o, r, t, K, dist)
        err = np.linalg.norm(proj.reshape(-1, 2) - p, axis=1)
        per_image.append(float(np.sqrt(np.mean(err**2))))
        worst = max(worst, float(err.max()))
    hull = cv2.convexHull(np.concatenate(img).reshape(-1, 1, 2))
    coverage = float(cv2.contourArea(hull)) / (w * h)
    result = IntrinsicsResult(K, dist.ravel()[:5], float(rms), per_image, worst, coverage,
                              spread, used, rejected, detector=detector)
    if spread < min_tilt_deg:
        return IntrinsicsResult(None, None, float(rms), per_image, worst, coverage, spread,
                                used, rejected, reason=(
                                    f"the board was never tilted (normals within {spread:.1f}"
                                    f" degrees): tilt it by 20-40 degrees in several "
                                    "directions"))
    return result
