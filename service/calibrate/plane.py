"""The light plane from board poses with the laser line across the board."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from service.calibrate.board import Board
from service.calibrate.intrinsics import find_corners
from service.measure.stripe import StripeParams, extract_stripe
from service.measure.triangulate import undistort_to_rays


@dataclass(frozen=True)
class BoardPlane:
    """A board's plane in the camera frame: unit normal n and offset d (n . X = d), mm."""

    normal: np.ndarray
    d: float
    reprojection_rms_px: float


def board_plane(image: np.ndarray, board: Board, K: np.ndarray, dist: np.ndarray
                ) -> BoardPlane | str:
    """Pose of the board in an image by PnP, as its plane; a reason string when not found."""
    c = find_corners(image, board)
    if c.points is None:
        return c.reason
    obj = board.object_points()
    ok, rvec, tvec = cv2.solvePnP(obj, c.points, K, dist, flags=cv2.SOLVEPNP_ITERATIVE)
    if not ok:
        return "board pose could not be solved"
    proj, _ = cv2.projectPoints(obj, rvec, tvec, K, dist)
    rms = float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - c.points) ** 2, axis=1))))
    R = cv2.Rodrigues(rvec)[0]
    n = R[:, 2]
    t = tvec.ravel()
    d = float(n @ t)
    if d < 0:
        n, d = -n, -d
    return BoardPlane(n, d, rms)


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
    pts, counts, rejected = [], [], {}
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
        rays = undistort_to_rays(stripe.xy, K, dist)
        rays3 = np.column_stack([rays, np.ones(len(rays))])
        s = plane.d / (rays3 @ plane.normal)
        pts.append(rays3 * s[:, None])
        counts.append(len(rays))
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
    return PlaneResult(n, d, float(np.sqrt(np.mean(res**2))), float(np.abs(res).max()),
                       len(allp), counts, per_pose, rejected)
