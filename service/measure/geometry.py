"""The calibrated geometry the core works with, as plain numpy (no pydantic in the core)."""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any

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

    @functools.cached_property
    def key(self) -> tuple[float, ...]:
        """Every number of the geometry, as a key for what is computed from it (kept: the
        arrays are not changed in place; a changed geometry is a new one)."""
        parts = [self.camera_matrix.ravel(), self.dist_coeffs.ravel(), self.plane_normal.ravel(),
                 [self.plane_d], self.axis_direction.ravel(),
                 [] if self.axis_point is None else self.axis_point.ravel()]
        return tuple(float(v) for part in parts for v in part)


def geometry_of(calibration: Any) -> RigGeometry:
    """The numeric form of a calibration document (``calib_store.model.Calibration``, or
    anything with its fields: ``image_size``, ``camera_matrix``, ``dist_coeffs``,
    ``light_plane.normal``/``.d``, ``axis.direction``/``.point``). Read by attribute, so the
    core needs nothing from the store."""
    axis = calibration.axis
    return RigGeometry(
        image_size=(int(calibration.image_size[0]), int(calibration.image_size[1])),
        camera_matrix=np.array(calibration.camera_matrix, np.float64),
        dist_coeffs=np.array(calibration.dist_coeffs, np.float64),
        plane_normal=np.array(calibration.light_plane.normal, np.float64),
        plane_d=float(calibration.light_plane.d),
        axis_direction=np.array(axis.direction, np.float64),
        axis_point=None if axis.point is None else np.array(axis.point, np.float64),
    )
