"""The light plane from board poses with the laser line across the board: from laser-off /
laser-on pairs (the line is their difference), or from laser-on images alone
(``laser_line``)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from service.calibrate.board import Board
from service.calibrate.intrinsics import find_corners
from service.calibrate.laser_line import (
    grey_of,
    line_colour,
    line_without_twin,
    on_one_line,
    pattern_image,
)
from service.measure.stripe import StripeParams, extract_stripe
from service.measure.triangulate import undistort_to_rays


@dataclass(frozen=True)
class BoardPlane:
    """A board's plane in the camera frame: unit normal n and offset d (n . X = d), mm."""

    normal: np.ndarray
    d: float
    reprojection_rms_px: float


@dataclass(frozen=True)
class BoardPose:
    """A board's pose by PnP (``X_cam = R(rvec) X_board + tvec``) and its plane."""

    rvec: np.ndarray
    tvec: np.ndarray
    plane: BoardPlane
    points: np.ndarray   # the target's points it was solved from, px
    objects: np.ndarray  # ... and where they are on the board, mm

    def box(self, board: Board, K: np.ndarray, dist: np.ndarray,
            shape: tuple[int, int]) -> tuple[int, int, int, int]:
        """The printed board's bounding box in the image (x0, y0, x1, y1), clipped to it."""
        u0, u1, v0, v1 = board.extent()
        corners = np.array([[u, v, 0.0] for u in (u0, u1) for v in (v0, v1)]) * board.square_mm
        img, _ = cv2.projectPoints(corners, self.rvec, self.tvec, K, dist)
        img = img.reshape(-1, 2)
        h, w = shape
        x0, y0 = np.clip(np.floor(img.min(axis=0)).astype(int), 0, [w, h])
        x1, y1 = np.clip(np.ceil(img.max(axis=0)).astype(int) + 1, 0, [w, h])
        return int(x0), int(y0), int(max(x0, x1)), int(max(y0, y1))


def board_pose(image: np.ndarray, board: Board, K: np.ndarray, dist: np.ndarray
               ) -> BoardPose | str:
    """Pose of the board in a grey image by PnP; a reason string when not found."""
    c = find_corners(image, board)
    if c.points is None:
        return c.reason
    return _solved(c.object_points(board), c.points, K, dist) or \
        "board pose could not be solved"


def _solved(obj: np.ndarray, points: np.ndarray, K: np.ndarray, dist: np.ndarray,
            keep: np.ndarray | None = None) -> BoardPose | None:
    """The pose from the points (those ``keep`` marks), or None."""
    o, p = (obj, points) if keep is None else (obj[keep], points[keep])
    ok, rvec, tvec = cv2.solvePnP(o, p, K, dist, flags=cv2.SOLVEPNP_ITERATIVE)
    if not ok:
        return None
    proj, _ = cv2.projectPoints(o, rvec, tvec, K, dist)
    rms = float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - p) ** 2, axis=1))))
    R = cv2.Rodrigues(rvec)[0]
    n = R[:, 2]
    t = tvec.ravel()
    d = float(n @ t)
    if d < 0:
        n, d = -n, -d
    return BoardPose(rvec, tvec, BoardPlane(n, d, rms), points, obj)


def clear_of_line(pose: BoardPose, board: Board, line_xy: np.ndarray, K: np.ndarray,
                  dist: np.ndarray) -> BoardPose:
    """The pose again without the target's points the laser line runs near (within half
    their spacing: a detector's window that takes in the line is pulled towards it), when
    enough stay; else as it was."""
    pts = pose.points
    if len(line_xy) == 0 or len(pts) < 8:
        return pose
    spacing = np.linalg.norm(pts[:, None] - pts[None], axis=-1)
    np.fill_diagonal(spacing, np.inf)
    near = np.array([np.min(np.linalg.norm(line_xy - p, axis=1)) for p in pts])
    keep = near > 0.5 * float(np.median(spacing.min(axis=1)))
    if keep.all() or keep.sum() < max(6, len(pts) // 2):
        return pose
    again = _solved(pose.objects, pts, K, dist, keep)
    return pose if again is None else BoardPose(again.rvec, again.tvec, again.plane, pts,
                                                pose.objects)


def board_plane(image: np.ndarray, board: Board, K: np.ndarray, dist: np.ndarray
                ) -> BoardPlane | str:
    """Pose of the board in an image by PnP, as its plane; a reason string when not found."""
    pose = board_pose(image, board, K, dist)
    return pose if isinstance(pose, str) else pose.plane


def fit_plane(points: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
    """Total-least-squares plane of 3-D points: (unit normal, d, singular values)."""
    centroid = points.mean(axis=0)
    _, s, vt = np.linalg.svd(points - centroid, full_matrices=False)
    n = vt[-1]
    d = float(n @ centroid)
    if d < 0:
        n, d = -n, -d
    return n, d, s


@dataclass(frozen=True)
class PlaneResult:
    """The light plane with its residuals, or why there is none."""

    normal: np.ndarray | None
    d: float = math.nan
    rms_mm: float = math.nan
    worst_mm: float = math.nan
    points: int = 0
    per_pose_points: list[int] = field(default_factory=list)
    per_pose_rms_mm: list[float] = field(default_factory=list)
    rejected: dict[int, str] = field(default_factory=dict)
    reason: str = ""
    how: dict[int, str] = field(default_factory=dict)
    """How each pose's line was found (a pose's index: its pair, or its laser-on image)."""
    normal_u_deg: float = math.nan
    """The normal's standard uncertainty, degrees, from the spread of the poses (each left
    out in turn: a jackknife)."""
    axis_u_mm: float = math.nan
    """The same for where the plane meets the camera's optical axis, mm."""

    def __bool__(self) -> bool:
        return self.normal is not None and not self.reason


def calibrate_plane(pairs: list[tuple[np.ndarray, np.ndarray]], board: Board, K: np.ndarray,
                    dist: np.ndarray, min_poses: int = 3,
                    min_points_per_pose: int = 30) -> PlaneResult:
    """Light plane from (laser off, laser on) image pairs taken at the same pose, light and
    exposure.

    The laser-off image gives the pose (PnP); the difference of the two is the laser line
    alone (the checker's edges cancel), whose centres' rays are intersected with the board
    plane; a total-least-squares plane through all poses' points is
    the light plane. Refuses too few poses with a laser line, and poses that do not span a
    plane (stripe lines all parallel and coplanar).
    """
    pts, counts, rejected, how = [], [], {}, {}
    for i, (board_img, laser_img) in enumerate(pairs):
        plane = board_plane(board_img, board, K, dist)
        if isinstance(plane, str):
            rejected[i] = plane
            continue
        if laser_img.shape != board_img.shape:
            rejected[i] = "the two images of the pose differ in size"
            continue
        diff = np.clip(laser_img.astype(np.int32) - board_img.astype(np.int32), 0, None)
        stripe = extract_stripe(diff.astype(np.uint16) if laser_img.dtype == np.uint16
                                else diff.astype(np.uint8),
                                StripeParams(curvature_correction=False))
        if len(stripe) < min_points_per_pose:
            rejected[i] = f"laser line missing or too short ({len(stripe)} points)"
            continue
        # On one straight line (the sheet meets the board's plane in one): a speck of noise
        # the difference left elsewhere does not tilt the plane.
        xy = on_one_line(stripe.xy, K, dist)
        if len(xy) < min_points_per_pose:
            rejected[i] = f"laser line missing or too short ({len(xy)} points on one line)"
            continue
        pts.append(on_plane(xy, plane, K, dist))
        counts.append(len(xy))
        how[i] = "the difference of the laser-off and laser-on images"
    return plane_of_poses(pts, counts, rejected, how, min_poses)


def on_plane(xy: np.ndarray, plane: BoardPlane, K: np.ndarray, dist: np.ndarray
             ) -> np.ndarray:
    """Image points (px) met with a board's plane: 3-D points in the camera frame, mm."""
    rays = undistort_to_rays(xy, K, dist)
    rays3 = np.column_stack([rays, np.ones(len(rays))])
    s = plane.d / (rays3 @ plane.normal)
    return rays3 * s[:, None]


def calibrate_plane_laser_on(images: list[np.ndarray], board: Board, K: np.ndarray,
                             dist: np.ndarray, min_poses: int = 3,
                             min_points_per_pose: int = 30) -> PlaneResult:
    """Light plane from laser-on images alone (no laser-off twin): each board's pose from its
    pattern, the line as the light above the pattern (``laser_line``; by its colour in a
    colour image). The pairs (``calibrate_plane``) stay the better way."""
    pts, counts, rejected, how = [], [], {}, {}
    for i, image in enumerate(images):
        pose = board_pose(grey_of(image), board, K, dist)
        if isinstance(pose, str):
            rejected[i] = pose
            continue
        box = pose.box(board, K, dist, image.shape[:2])
        x0, y0, x1, y1 = box
        colour = line_colour(image[y0:y1, x0:x1], np.ones((y1 - y0, x1 - x0), bool))
        if colour is not None:  # the pattern again where the line hardly shows
            clean = board_pose(pattern_image(image, colour), board, K, dist)
            pose = pose if isinstance(clean, str) else clean
        line = line_without_twin(image, board, pose.rvec, pose.tvec, K, dist, box)
        if colour is None:  # the pattern seen through the line: its points by it left out
            pose = clear_of_line(pose, board, line.points, K, dist)
        if len(line.points) < min_points_per_pose:
            rejected[i] = (f"laser line missing or too short on the board "
                           f"({len(line.points)} points, looked for in {line.how})")
            continue
        pts.append(on_plane(line.points, pose.plane, K, dist))
        counts.append(len(line.points))
        how[i] = f"laser on only: {line.how}"
    return plane_of_poses(pts, counts, rejected, how, min_poses)


MAX_PLANE_RMS_MM = 1.0
"""A plane whose own points lie farther from it than this, RMS, is refused: they contradict
it (a line found on something else than the sheet's trace, a pose's board plane wrong). A
laser line on a board is a few tenths of a millimetre wide; a good plane's points lie tens
of micrometres from it."""


def plane_of_poses(pts: list[np.ndarray], counts: list[int], rejected: dict[int, str],
                   how: dict[int, str], min_poses: int) -> PlaneResult:
    """The plane through every pose's points (``pts``: each pose's 3-D points, mm, in the
    camera frame; ``counts``: how many each), or why there is none: too few poses, poses
    that do not span a plane, or points that lie farther from the plane than
    ``MAX_PLANE_RMS_MM`` (the figures kept, each pose's too)."""
    if len(counts) < min_poses:
        return PlaneResult(None, per_pose_points=counts, rejected=rejected, reason=(
            f"the laser line was measured on {len(counts)} board poses, need {min_poses}: "
            "turn the laser on and move the board to different distances and tilts"))
    allp = np.concatenate(pts)
    n, d, sv = fit_plane(allp)
    if sv[1] < 0.05 * sv[0]:
        return PlaneResult(None, per_pose_points=counts, rejected=rejected, reason=(
            "the laser lines do not span a plane: tilt the board between poses"))
    res = allp @ n - d
    per_pose = [float(np.sqrt(np.mean(r**2))) for r in np.split(res, np.cumsum(counts)[:-1])]
    rms, worst = float(np.sqrt(np.mean(res**2))), float(np.abs(res).max())
    reason = ""
    if rms > MAX_PLANE_RMS_MM:
        poses = ", ".join(f"{r:.1f}" for r in per_pose)
        reason = (f"the plane's own points lie {rms:.1f} mm RMS from it (worst {worst:.1f} "
                  f"mm; by pose {poses} mm), more than {MAX_PLANE_RMS_MM:g} mm: they do not "
                  "lie on one plane. Check that the line found is the laser's on the board "
                  "(its colour, the board's margin) and that the board is flat; take the "
                  "poses again")
    normal_u, axis_u = leave_one_pose_out(pts, n)
    return PlaneResult(None if reason else n, d, rms, worst, len(allp), counts, per_pose,
                       rejected, reason, how, normal_u, axis_u)


def leave_one_pose_out(pts: list[np.ndarray], normal: np.ndarray) -> tuple[float, float]:
    """The plane's standard uncertainties from the spread of its poses: the plane fitted
    with each pose left out in turn, the jackknife's spread of the normals (degrees) and of
    where the plane meets the optical axis (mm; ``z = d / n_z``). NaN with fewer than three
    poses, or a plane along the axis."""
    k = len(pts)
    if k < 3:
        return math.nan, math.nan
    normals, crossings = [], []
    for i in range(k):
        n, d, _ = fit_plane(np.concatenate(pts[:i] + pts[i + 1:]))
        if n @ normal < 0:
            n, d = -n, -d
        normals.append(n)
        crossings.append(d / n[2] if abs(n[2]) > 1e-9 else math.nan)
    mean = np.mean(normals, axis=0)
    mean /= np.linalg.norm(mean)
    angles = np.arccos(np.clip(np.asarray(normals) @ mean, -1.0, 1.0))
    z = np.asarray(crossings)
    scale = (k - 1) / k
    return (math.degrees(float(np.sqrt(scale * np.sum(angles ** 2)))),
            float(np.sqrt(scale * np.sum((z - z.mean()) ** 2))))
