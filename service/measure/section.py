"""3-D stripe points to 2-D coordinates: on the section perpendicular to the shaft axis (paper
Eq. 16-18, the "virtual plane"), or within the light plane (for the paper's ellipse fit).

Projecting along the axis onto a perpendicular plane and expressing the result in an orthonormal
basis ``(e1, e2)`` of that plane is the same as taking ``(X . e1, X . e2)``: where the plane sits
along the axis does not matter.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from service.measure.robust import row_index, rows

if TYPE_CHECKING:  # an annotation only: the extractor's kernels are numba's (0.2 s to import)
    from service.measure.stripe import StripePoints


def orthonormal_basis(direction: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors ``e1, e2`` that with ``direction`` form a right-handed basis.

    Parameters
    ----------
    direction : ndarray, shape (3,)
        Any non-zero vector; it is normalised here.

    Returns
    -------
    e1, e2 : ndarray, shape (3,)
        ``e1 x e2`` is parallel to ``direction``.
    """
    e1, e2 = _basis(tuple(float(v) for v in np.asarray(direction, np.float64).ravel()))
    return e1.copy(), e2.copy()


@functools.lru_cache(maxsize=64)
def _basis(direction: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
    # Cached: the same axis is asked for several times a frame, and np.cross is slow on (3,).
    a = np.array(direction)
    a = a / np.linalg.norm(a)
    ref = np.eye(3)[int(np.argmin(np.abs(a)))]  # the axis least aligned with a
    e1 = np.cross(a, ref)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(a, e1)
    return e1, e2


def project_to_section(points: np.ndarray, axis_direction: np.ndarray) -> np.ndarray:
    """Project 3-D points along the axis onto the perpendicular plane.

    Parameters
    ----------
    points : ndarray, shape (N, 3)
        Camera-frame points, mm.
    axis_direction : ndarray, shape (3,)
        Spindle axis direction.

    Returns
    -------
    ndarray, shape (N, 2)
        Section coordinates ``(X . e1, X . e2)``, mm. A point on the axis maps to the axis's
        own section coordinates, so the centre of a turned surface is the axis there.
    """
    return points @ _section_matrix(
        tuple(float(v) for v in np.asarray(axis_direction, np.float64).ravel()))


@functools.lru_cache(maxsize=64)
def _section_matrix(direction: tuple[float, ...]) -> np.ndarray:
    """``(e1 e2)`` as the columns of a (3, 2) matrix (read-only: kept per axis)."""
    e1, e2 = _basis(direction)
    out = np.column_stack([e1, e2])
    out.flags.writeable = False
    return out


def light_plane_coordinates(
    points: np.ndarray, plane_normal: np.ndarray, axis_direction: np.ndarray
) -> np.ndarray:
    """2-D coordinates of points within the light plane.

    The first basis vector is the axis direction projected into the plane (the major axis of
    the section ellipse), the second is ``n x u1``.

    Parameters
    ----------
    points : ndarray, shape (N, 3)
        Camera-frame points on the light plane, mm.
    plane_normal : ndarray, shape (3,)
        Light-plane unit normal.
    axis_direction : ndarray, shape (3,)
        Spindle axis direction.

    Returns
    -------
    ndarray, shape (N, 2)
        In-plane coordinates, mm.
    """
    u1, u2 = light_plane_basis(plane_normal, axis_direction)
    return np.column_stack([points @ u1, points @ u2])


def light_plane_basis(
    plane_normal: np.ndarray, axis_direction: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Orthonormal in-plane basis ``(u1, u2)``: ``u1`` along the axis projected into the plane."""
    n = np.asarray(plane_normal, np.float64)
    a = np.asarray(axis_direction, np.float64)
    u1 = a - (a @ n) * n
    u1 /= np.linalg.norm(u1)
    return u1, np.cross(n, u1)


def section_circle_on_plane(center: tuple[float, float], radius: float,
                            axis_direction: np.ndarray, plane_normal: np.ndarray,
                            plane_d: float, n: int = 180) -> np.ndarray:
    """The inverse of the projection for a fitted section: where the circle's surface meets
    the light plane (the curve the stripe lies on), for drawing it over the image.

    Parameters
    ----------
    center : (float, float)
        Section centre ``(c1, c2)`` in the basis of ``orthonormal_basis(axis_direction)``, mm.
    radius : float
        Section radius, mm.
    axis_direction, plane_normal : ndarray, shape (3,)
        Spindle axis direction; light-plane unit normal.
    plane_d : float
        Light-plane offset (``n . X = d``), mm.
    n : int
        Number of points around the circle.

    Returns
    -------
    ndarray, shape (n, 3)
        Camera-frame points, mm (empty when the axis lies in the light plane).
    """
    a = np.asarray(axis_direction, np.float64)
    a = a / np.linalg.norm(a)
    e1, e2 = orthonormal_basis(a)
    na = float(plane_normal @ a)
    if abs(na) < 1e-9:
        return np.empty((0, 3))
    th = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    s = ((center[0] + radius * np.cos(th))[:, None] * e1
         + (center[1] + radius * np.sin(th))[:, None] * e2)
    t = (plane_d - s @ plane_normal) / na
    return s + t[:, None] * a


def first_hit_on_cylinder(rays_xy: np.ndarray, axis_point: np.ndarray,
                          axis_direction: np.ndarray, radius: float
                          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where camera rays first meet a cylinder, and its outward normal there.

    Parameters
    ----------
    rays_xy : ndarray, shape (..., 2)
        Undistorted normalised rays ``(x, y)`` (the ray is ``s (x, y, 1)``, s > 0).
    axis_point, axis_direction : ndarray, shape (3,)
        A point on the cylinder's axis and its unit direction, camera frame, mm.
    radius : float
        Radius, mm.

    Returns
    -------
    hit : ndarray of bool, shape (...)
        The ray meets the cylinder in front of the camera.
    points, normals : ndarray, shape (..., 3)
        The first intersection (NaN for a miss), mm, and the unit surface normal there.
    """
    a, a0 = np.asarray(axis_direction, np.float64), np.asarray(axis_point, np.float64)
    r = np.concatenate([rays_xy, np.ones((*rays_xy.shape[:-1], 1))], axis=-1)
    r_perp = r - (r @ a)[..., None] * a
    w = -a0
    w_perp = w - (w @ a) * a
    qa = np.sum(r_perp * r_perp, axis=-1)
    qb = r_perp @ w_perp
    qc = w_perp @ w_perp - radius * radius
    disc = qb * qb - qa * qc
    hit = disc > 0
    s = np.where(hit, (-qb - np.sqrt(np.where(hit, disc, 0.0))) / np.maximum(qa, 1e-300),
                 np.nan)
    hit &= s > 0
    points = r * s[..., None]
    rel = points - a0
    nrm = rel - (rel @ a)[..., None] * a
    nrm /= np.maximum(np.linalg.norm(nrm, axis=-1, keepdims=True), 1e-300)
    return hit, points, nrm


@dataclass(frozen=True)
class SectionPoints:
    """Stripe points carried through triangulation and projection.

    Attributes
    ----------
    stripe : StripePoints
        Image centres (px) with a finite 3-D point.
    points3d : ndarray, shape (N, 3)
        Camera-frame points on the light plane, mm.
    section : ndarray, shape (N, 2)
        Coordinates on the plane perpendicular to the axis, mm.
    """

    stripe: StripePoints
    points3d: np.ndarray
    section: np.ndarray

    def subset(self, keep: np.ndarray) -> SectionPoints:
        """The points selected by a boolean mask or index array (these points themselves
        when the mask keeps them all)."""
        if keep.dtype == np.bool_ and keep.all():
            return self
        i = row_index(keep)
        return SectionPoints(self.stripe.subset(i), rows(self.points3d, i), rows(self.section, i))
