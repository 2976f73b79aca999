"""Pixels to 3-D points: undistort to a normalised ray, intersect the ray with the light plane.

A stripe centre at pixel ``(u, v)`` is undistorted to ``(x_u, y_u)``; its ray from the camera
centre is ``r = (x_u, y_u, 1)`` and the point on the plane ``n . X = d`` is ``X = d r / (n . r)``
(paper Eq. 14-15, with a unit normal instead of the paper's scaled coefficients).
"""

from __future__ import annotations

import math

import cv2
import numba
import numpy as np

# Iterative undistortion settles to well below a micro-pixel on lens distortions seen in
# practice; OpenCV's default (5 iterations) does not for strong barrel distortion.
_UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-12)


def undistort_to_rays(
    points_px: np.ndarray, camera_matrix: np.ndarray, dist_coeffs: np.ndarray
) -> np.ndarray:
    """Normalised, undistorted image coordinates of pixel positions.

    Parameters
    ----------
    points_px : ndarray, shape (N, 2)
        Pixel positions (x, y), OpenCV convention.
    camera_matrix : ndarray, shape (3, 3)
        Intrinsic matrix, pixels.
    dist_coeffs : ndarray
        OpenCV distortion coefficients.

    Returns
    -------
    ndarray, shape (N, 2)
        ``(x_u, y_u)``: the ray through each pixel is ``(x_u, y_u, 1)`` (unitless).
    """
    pts = np.ascontiguousarray(points_px, dtype=np.float64).reshape(-1, 1, 2)
    if pts.shape[0] == 0:
        return np.empty((0, 2))
    out = cv2.undistortPointsIter(
        pts, np.asarray(camera_matrix, np.float64), np.asarray(dist_coeffs, np.float64),
        None, None, _UNDISTORT_CRITERIA,
    )
    return out.reshape(-1, 2)


def intersect_plane(rays_xy: np.ndarray, normal: np.ndarray, d: float) -> np.ndarray:
    """Points where camera rays meet the plane ``n . X = d``.

    Parameters
    ----------
    rays_xy : ndarray, shape (N, 2)
        Normalised image coordinates; ray ``i`` is ``(x_i, y_i, 1)``.
    normal : ndarray, shape (3,)
        Unit plane normal (camera frame).
    d : float
        Plane offset, mm.

    Returns
    -------
    ndarray, shape (N, 3)
        Camera-frame points in mm; rows are NaN where a ray runs (nearly) parallel to the plane
        or meets it behind the camera.
    """
    n = np.asarray(normal, np.float64)
    return _on_plane(np.ascontiguousarray(rays_xy, np.float64), float(n[0]), float(n[1]),
                     float(n[2]), float(d))


@numba.njit(cache=True, nogil=True)
def _on_plane(rays_xy: np.ndarray, n0: float, n1: float, n2: float, d: float) -> np.ndarray:
    """``intersect_plane`` compiled: one pass, no temporary arrays (a frame's few hundred
    points cost more in numpy's calls than in arithmetic)."""
    out = np.empty((rays_xy.shape[0], 3))
    for i in range(rays_xy.shape[0]):
        x, y = rays_xy[i, 0], rays_xy[i, 1]
        denom = x * n0 + y * n1 + n2
        scale = d / denom if abs(denom) >= 1e-9 else math.nan
        if not scale > 0:
            scale = math.nan
        out[i, 0] = x * scale
        out[i, 1] = y * scale
        out[i, 2] = scale
    return out


def triangulate(
    points_px: np.ndarray, camera_matrix: np.ndarray, dist_coeffs: np.ndarray,
    normal: np.ndarray, d: float,
) -> np.ndarray:
    """3-D camera-frame points (mm) of stripe centres (px) on the light plane ``n . X = d``."""
    return intersect_plane(undistort_to_rays(points_px, camera_matrix, dist_coeffs), normal, d)
