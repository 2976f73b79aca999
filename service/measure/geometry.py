"""The calibrated geometry the core works with, as plain numpy (no pydantic in the core)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class RigGeometry:
    """Camera intrinsics, light plane and spindle axis, all in the camera frame, in mm.

    Attributes
    ----------
    image_size : tuple of int
        (width, height) in pixels.
    camera_matrix : ndarray, shape (3, 3)
        OpenCV intrinsic matrix (pixels).
    dist_coeffs : ndarray
        OpenCV distortion coefficients ``[k1, k2, p1, p2, k3, ...]``.
    plane_normal : ndarray, shape (3,)
        Unit normal ``n`` of the light plane; plane points satisfy ``n . X = plane_d``.
    plane_d : float
        Plane offset in mm.
    axis_direction : ndarray, shape (3,)
        Unit direction of the spindle axis.
    axis_point : ndarray, shape (3,) or None
        A point on the spindle axis in mm, when calibrated.
    """

    image_size: tuple[int, int]
    camera_matrix: np.ndarray
    dist_coeffs: np.ndarray
    plane_normal: np.ndarray
    plane_d: float
    axis_direction: np.ndarray
    axis_point: np.ndarray | None = None
