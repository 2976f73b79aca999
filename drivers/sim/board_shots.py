"""Calibration images of the simulated rig: a target (a chessboard or a circle grid,
``service.calibrate.board``) at chosen poses, with or without the laser line across it, and
clamped between the lathe centres at chosen rotations.

The board is a plane; its own frame has the target's first point at the origin, x along the
columns, z out of the board. Each
pixel's ray is intersected with the board plane; each pixel integrates over its area (3x3
samples, 12x12 at edges), then the image is blurred and given shot and read noise like the
shaft images. The laser line is the light sheet's Gaussian profile around the plane,
brighter on white squares.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from drivers.sim.rig import RigConfig, ShaftRenderer, _rotation
from service.calibrate.board import DEFAULT_BOARD, Board, parse_board

EDGE_SAMPLES = {"charuco": 6}
"""Samples a side of a pixel an edge runs through (12 unless named): a ChArUco board's
markers are mostly edges, and its detector's corners are a tenth of a pixel off anyway."""


@dataclass(frozen=True)
class BoardPose:
    """Board frame in the camera frame: ``X_cam = R X_board + t`` (mm)."""

    R: np.ndarray
    t: np.ndarray

    @property
    def normal(self) -> np.ndarray:
        """Board plane normal in the camera frame."""
        return self.R[:, 2]


class BoardRenderer:
    """Renders calibration images for a rig (reusing its camera, light sheet and noise)."""

    def __init__(self, rig: ShaftRenderer, board: Board | None = None) -> None:
        self.rig = rig
        self.cfg: RigConfig = rig.config
        self.board = board or Board()
        self._pose = rig._pose

    def pose_facing_camera(self, tilt_x_deg: float, tilt_y_deg: float, distance_mm: float,
                           shift_mm: tuple[float, float] = (0.0, 0.0),
                           spin_deg: float = 0.0) -> BoardPose:
        """A board roughly facing the camera, tilted about x and y, centred on the optical
        axis (plus ``shift_mm``) at ``distance_mm``."""
        R = _rotation(180.0 + tilt_x_deg, tilt_y_deg, spin_deg)
        cx, cy = self._middle()
        centre = np.array([shift_mm[0], shift_mm[1], distance_mm])
        t = centre - R @ np.array([cx, cy, 0.0])
        return BoardPose(R, t)

    def pose_on_spindle(self, rotation_deg: float, along_axis_mm: float = 0.0) -> BoardPose:
        """The board clamped between the centres, its plane containing the spindle axis,
        turned by ``rotation_deg`` about it (0: facing the camera)."""
        p = self._pose
        a = p.axis_direction
        a0 = p.axis_point
        # Board x along the axis; board y in the plane, perpendicular to it; z its normal.
        toward_cam = -a0 / np.linalg.norm(a0)
        y0 = np.cross(toward_cam, a)
        y0 /= np.linalg.norm(y0)
        th = math.radians(rotation_deg)
        z0 = np.cross(a, y0)  # faces the camera at 0 degrees
        y = math.cos(th) * y0 + math.sin(th) * z0
        z = np.cross(a, y)
        R = np.column_stack([a, y, z])
        cx, cy = self._middle()
        # The axis runs along the board's middle row; shift along the axis to taste.
        t = a0 + (along_axis_mm - cx) * a - cy * y
        return BoardPose(R, t)

    def _markers(self) -> tuple[np.ndarray, np.ndarray]:
        """A ChArUco board's markers (a cell a bit) and which square holds which, as OpenCV
        prints them; blanks for another target."""
        b = self.board
        if b.kind != "charuco":
            return np.zeros((1, 1, 1), np.uint8), np.zeros((1, 1), np.int64)
        from service.calibrate.intrinsics import aruco_board

        board = aruco_board(b)
        dictionary = board.getDictionary()
        ids = np.array(board.getIds()).ravel()
        marks = np.stack([cv2.aruco.generateImageMarker(dictionary, int(i),
                                                        dictionary.markerSize + 2)
                          for i in ids])
        square_mark = np.full((b.rows, b.cols), -1, np.int64)
        for k, corners in enumerate(board.getObjPoints()):
            cx, cy = np.asarray(corners)[:, :2].mean(axis=0) / b.square_mm
            square_mark[int(cy), int(cx)] = k
        return marks, square_mark

    def project(self, pose: BoardPose, points_mm: np.ndarray) -> np.ndarray:
        """Where points of the board (``Board.object_points``' frame, mm) are in the image,
        px: the truth a detector is checked against."""
        pts = np.array(points_mm, float).reshape(-1, 3)
        if self.board.kind == "charuco":  # its print is read the right way: y down the print
            pts[:, 1] = self.board.rows * self.board.square_mm - pts[:, 1]
        cam = pts @ pose.R.T + pose.t
        img, _ = cv2.projectPoints(cam, np.zeros(3), np.zeros(3), self.cfg.camera_matrix(),
                                   np.array(self.cfg.dist_coeffs))
        return img.reshape(-1, 2)

    def _middle(self) -> tuple[float, float]:
        """The middle of the target's points in the board's frame, mm."""
        pts = self.board.object_points()
        return (float(pts[:, 0].min() + pts[:, 0].max()) / 2,
                float(pts[:, 1].min() + pts[:, 1].max()) / 2)

    def _bbox(self, pose: BoardPose) -> tuple[int, int, int, int]:
        """Pixel bounding box of the printed board, with a margin for the blur."""
        b = self.board
        u0, u1, v0, v1 = b.extent()
        xs = np.array([u0 - 1.0, u1 + 1.0]) * b.square_mm
        ys = np.array([v0 - 1.0, v1 + 1.0]) * b.square_mm
        corners = np.array([[x, y, 0.0] for x in xs for y in ys])
        cam = corners @ pose.R.T + pose.t
        w, h = self.cfg.image_size
        if (cam[:, 2] <= 1.0).any():
            return 0, 0, w, h
        img, _ = cv2.projectPoints(cam, np.zeros(3), np.zeros(3), self.cfg.camera_matrix(),
                                   np.array(self.cfg.dist_coeffs))
        img = img.reshape(-1, 2)
        x0 = int(np.clip(np.floor(img[:, 0].min()) - 8, 0, w))
        x1 = int(np.clip(np.ceil(img[:, 0].max()) + 8, 0, w))
        y0 = int(np.clip(np.floor(img[:, 1].min()) - 8, 0, h))
        y1 = int(np.clip(np.ceil(img[:, 1].max()) + 8, 0, h))
        return x0, y0, max(x0, x1), max(y0, y1)

    def render(self, pose: BoardPose, laser: bool = False, frame_index: int = 0,
               ambient_dn: float = 90.0) -> np.ndarray:
        """One 8-bit image of the board at ``pose`` (with the laser line when asked).

        Each pixel integrates the light over its area, as a sensor does: 3x3 samples per
        pixel, and 12x12 where the samples or the neighbours disagree (the squares' edges and
        the board's border), so that a corner's position is not biased by the sampling.
        Take the laser-off and laser-on images of a pose at the same light and exposure: their
        difference is the laser line alone.
        """
        cfg = self.cfg
        w, h = cfg.image_size
        K = cfg.camera_matrix()
        x0, y0, x1, y1 = self._bbox(pose)
        # Undistorted normalised rays of the pixel centres; a pixel's area is covered by
        # offsetting them (small offsets, so linear in x, y).
        rays = self.rig._rays(1)[y0:y1, x0:x1]
        acc = np.zeros((h, w), np.float32)
        lit = np.zeros((h, w), np.float32)
        if y1 > y0 and x1 > x0:
            a, li, edge = self._integrate(pose, rays[..., 0], rays[..., 1], K, 3, laser)
            # An edge may run between the samples of a pixel: its neighbours then differ.
            step = np.zeros_like(edge)
            step[:, 1:] |= a[:, 1:] != a[:, :-1]
            step[1:, :] |= a[1:, :] != a[:-1, :]
            edge |= step | np.roll(step, -1, axis=1) | np.roll(step, -1, axis=0)
            iy, ix = np.nonzero(edge)
            if iy.size:
                fa, fl, _ = self._integrate(pose, rays[iy, ix, 0], rays[iy, ix, 1], K,
                                            EDGE_SAMPLES.get(self.board.kind, 12),
                                            laser)
                a[iy, ix], li[iy, ix] = fa, fl
            acc[y0:y1, x0:x1], lit[y0:y1, x0:x1] = a, li
        img = cfg.background_dn + ambient_dn * acc
        if laser:
            img = img + cfg.peak_dn * lit
        img = cv2.GaussianBlur(img.astype(np.float32), (0, 0), cfg.blur_px)
        rng = np.random.default_rng([self.rig.seed, 7919, int(frame_index)])
        sigma = np.sqrt(np.maximum(img, 0) / cfg.electrons_per_dn + cfg.read_noise_dn**2)
        img = img + sigma * rng.standard_normal(img.shape, dtype=np.float32)
        return np.clip(np.rint(img), 0, 255).astype(np.uint8)

    def _integrate(self, pose: BoardPose, rx: np.ndarray, ry: np.ndarray, K: np.ndarray,
                   ss: int, laser: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Mean reflectance and laser light over the pixels whose centre rays are (rx, ry),
        from ``ss x ss`` samples each, and where the samples of a pixel disagree."""
        offsets = np.array(_offsets(ss)) / [K[0, 0], K[1, 1]]
        b, p = self.board, self._pose
        marks, square_mark = self._markers()
        board = np.array([b.square_mm, b.cols, b.rows, b.margin_squares,
                          ("chess", "circles", "acircles", "charuco").index(b.kind),
                          b.dot_radius, b.marker_mm], float)
        sheet = np.array([*p.plane_normal, p.plane_d, self.cfg.sheet_sigma_mm], float)
        shape = rx.shape
        # Imported here: the kernels are numba's (0.2 s to import), and a simulator that
        # never shows a board (most of them) need not pay it.
        from drivers.sim.board_kernels import integrate_pixels

        acc, lit, edge = integrate_pixels(
            np.ascontiguousarray(rx, float).ravel(), np.ascontiguousarray(ry, float).ravel(),
            offsets, np.ascontiguousarray(pose.R, float), np.asarray(pose.t, float), board,
            sheet, laser, marks, square_mark)
        return acc.reshape(shape), lit.reshape(shape), edge.reshape(shape)


def _offsets(ss: int) -> list[tuple[float, float]]:
    """Sample positions within a pixel (px from its centre), ``ss x ss`` on a regular grid."""
    d = (np.arange(ss) + 0.5) / ss - 0.5
    return [(float(ox), float(oy)) for ox in d for oy in d]


@dataclass(frozen=True)
class Shot:
    """One image of a calibration session: what the technician sets up, and which session
    kind it is (``view``, ``plane_off``, ``plane_on``, ``axis``)."""

    kind: str
    name: str
    frame_index: int
    tilt_x_deg: float = 0.0
    tilt_y_deg: float = 0.0
    distance_mm: float = 400.0
    shift_mm: tuple[float, float] = (0.0, 0.0)
    rotation_deg: float | None = None   # on the spindle, turned by this much
    laser: bool = False

    def pose(self, br: BoardRenderer) -> BoardPose:
        """The board's pose on this rig."""
        if self.rotation_deg is not None:
            return br.pose_on_spindle(self.rotation_deg)
        return br.pose_facing_camera(self.tilt_x_deg, self.tilt_y_deg, self.distance_mm,
                                     self.shift_mm)


def session_shots() -> list[Shot]:
    """The simulated session: 14 tilted views, 4 laser-off / laser-on pose pairs, 7 spindle
    rotations from -45 to 45 degrees."""
    shots, k = [], 0
    for tx in (-25, 0, 25):
        for ty in (-25, 0, 25):
            for shift in ((0, 0), (-20, -15), (20, 15)):
                if k % 2 == 0:
                    shots.append(Shot("view", f"view_{k:02d}", k, tx, ty, (380, 420, 400)[k % 3],
                                      shift))
                k += 1
    for i, (tx, ty, d) in enumerate([(20, 0, 290), (-20, 0, 310), (0, 20, 300), (0, -20, 295)]):
        shots.append(Shot("plane_off", f"pose{i}_off", 100 + i, tx, ty, d))
        shots.append(Shot("plane_on", f"pose{i}_on", 200 + i, tx, ty, d, laser=True))
    for i, a in enumerate((-45, -30, -15, 0, 15, 30, 45)):
        shots.append(Shot("axis", f"rot_{a:+03d}", 300 + i, rotation_deg=a))
    return shots


def render_set(output: str, seed: int = 0, board: Board | None = None) -> dict:
    """A simulated calibration session written as image files (``shaftgauge calibrate
    render``): board views, laser pairs, spindle rotations, masters (30 and 40 mm), and the
    rig's true calibration to compare with."""
    out = Path(output)
    for sub in ("views", "plane", "axis", "master30", "master40"):
        (out / sub).mkdir(parents=True, exist_ok=True)
    rig = ShaftRenderer(RigConfig(), seed=seed)
    br = BoardRenderer(rig, board or parse_board(DEFAULT_BOARD))
    folder = {"view": "views", "plane_off": "plane", "plane_on": "plane", "axis": "axis"}
    for shot in session_shots():
        cv2.imwrite(str(out / folder[shot.kind] / f"{shot.name}.png"),
                    br.render(shot.pose(br), laser=shot.laser, frame_index=shot.frame_index))
    for d, sub in ((30.0, "master30"), (40.0, "master40")):
        for i in range(10):
            cv2.imwrite(str(out / sub / f"frame_{i:02d}.png"), rig.render(d, 1000 + i))
    (out / "truth.json").write_text(rig.calibration.to_json() + "\n")
    return {"output": str(out), "board": br.board.describe()}
