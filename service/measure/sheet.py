"""The light sheet's thickness on a curved surface: where the stripe's smoothed ridge lies
relative to the sheet's centre plane, and the radial error that leaves in each section point.

The sheet has a Gaussian thickness profile about its centre plane (the calibrated light plane).
Across the stripe the camera sees that profile laid on the shaft: warped by the cylinder's
curvature and by foreshortening that changes across the stripe. The profile is symmetric in
distance from the plane but its image is not, and the extractor finds the maximum of the
image smoothed by the lens blur and its own derivative filters: a ridge a few hundredths of a
pixel off the centre plane's image, always toward the same side where the camera looks
obliquely. At 300 mm that is a fraction of a micrometre, growing with the view angle: small
per point, but the same in every frame, so no averaging of frames removes it.

This module predicts that offset from the fitted section (a cylinder about the fitted centre)
and the calibration: for sample points along the arc it casts rays across the stripe, takes
the sheet's profile on the cylinder, smooths it as the extractor does, finds the ridge, and
triangulates it as the measurement does. Pure numerics; no image is read.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.ndimage import gaussian_filter1d

from service.measure import sheet_kernels
from service.measure.geometry import RigGeometry
from service.measure.section import first_hit_on_cylinder, orthonormal_basis
from service.measure.triangulate import intersect_plane, undistort_to_rays


def _to_3d(section: np.ndarray, geometry: RigGeometry) -> np.ndarray:
    """Points of the given section coordinates that lie on the light plane, camera frame."""
    e1, e2 = orthonormal_basis(geometry.axis_direction)
    a = geometry.axis_direction / np.linalg.norm(geometry.axis_direction)
    base = section[:, :1] * e1 + section[:, 1:] * e2
    t = (geometry.plane_d - base @ geometry.plane_normal) / float(a @ geometry.plane_normal)
    return base + t[:, None] * a


def arc_angles(section: np.ndarray, center: np.ndarray) -> tuple[np.ndarray, float]:
    """Angles of section points about ``center``, unwrapped about the arc's middle, and that
    middle (radians)."""
    ang, mid = sheet_kernels.arc_angles(np.ascontiguousarray(section, np.float64),
                                        float(center[0]), float(center[1]))
    return ang, float(mid)


@dataclass(frozen=True)
class Crossings:
    """The fitted cylinder seen across the stripe at sample points along the arc.

    Attributes
    ----------
    angle_rad : ndarray, shape (K,)
        Sample angles about the section centre, radians.
    q, normal : ndarray, shape (K, 2)
        Image of the section (the plane's line on the cylinder) and its unit normal there, px.
    u : ndarray, shape (M,)
        Offsets across the stripe along ``normal``, px (symmetric, ``u[M // 2] == 0``).
    dist : ndarray, shape (K, M)
        Distance from the light plane of the surface each offset sees, mm (NaN: no surface).
    normals : ndarray, shape (K, M, 3)
        Surface normal there, camera frame.
    slope_mm_per_px : ndarray, shape (K,)
        Distance from the plane per pixel across the stripe, at its centre, mm/px: the image
        width of the sheet profile is ``sheet_sigma_mm / slope``.
    """

    angle_rad: np.ndarray
    q: np.ndarray
    normal: np.ndarray
    u: np.ndarray
    dist: np.ndarray
    normals: np.ndarray
    slope_mm_per_px: np.ndarray


def cross_the_stripe(center: np.ndarray, radius: float, angles_rad: np.ndarray,
                     geometry: RigGeometry, smoothing_px: float, step_px: float = 0.2
                     ) -> Crossings:
    """Cast rays across the stripe at ``angles_rad`` around a section circle (centre mm,
    radius mm) onto the cylinder it belongs to, every ``step_px``, as far either side as a
    ridge smoothed by ``smoothing_px`` (px) can be moved by: ``4 smoothing + 4`` px."""
    angles = np.asarray(angles_rad, np.float64)
    k = len(angles)
    # The section's image and its normal (from neighbours 1e-4 rad on).
    ring = np.column_stack([np.cos(angles), np.sin(angles)])
    ahead = np.column_stack([np.cos(angles + 1e-4), np.sin(angles + 1e-4)])
    pts = np.concatenate([_to_3d(center + radius * ring, geometry),
                          _to_3d(center + radius * ahead, geometry)])
    img, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), geometry.camera_matrix,
                               geometry.dist_coeffs)
    img = img.reshape(-1, 2)
    q, tangent = img[:k], img[k:] - img[:k]
    tangent /= np.maximum(np.linalg.norm(tangent, axis=1, keepdims=True), 1e-300)
    normal = np.column_stack([-tangent[:, 1], tangent[:, 0]])
    n_half = round((4.0 * smoothing_px + 4.0) / step_px)
    u = step_px * np.arange(-n_half, n_half + 1)
    samples = q[:, None, :] + u[None, :, None] * normal[:, None, :]
    rays = undistort_to_rays(samples.reshape(-1, 2), geometry.camera_matrix,
                             geometry.dist_coeffs)
    dist, normals = _plane_distance_on_cylinder(rays, center, radius, geometry)
    dist = dist.reshape(k, len(u))
    slope = np.abs(dist[:, n_half + 1] - dist[:, n_half - 1]) / (2 * step_px)
    return Crossings(angles, q, normal, u, dist, normals.reshape(k, len(u), 3), slope)


def ridge_bias(crossings: Crossings, geometry: RigGeometry, center: np.ndarray, radius: float,
               sheet_sigma_mm: float, smoothing_px: float,
               light_direction: np.ndarray | None = None) -> np.ndarray:
    """Radial error (mm) of the stripe's ridge at each of ``crossings``' angles: NaN where
    the camera does not see the surface across the stripe.

    The sheet's Gaussian profile (``sheet_sigma_mm``) on the surface, shaded by the cosine of
    the incidence when ``light_direction`` (unit, toward the laser) is given, smoothed by
    ``smoothing_px`` as the extractor sees it; its maximum is triangulated on the light plane
    as a stripe centre is.
    """
    c = crossings
    k, m = c.dist.shape
    if sheet_sigma_mm <= 0:
        return np.zeros(k)
    step = float(c.u[1] - c.u[0])
    profile = np.exp(-0.5 * (np.nan_to_num(c.dist, nan=np.inf) / sheet_sigma_mm) ** 2)
    if light_direction is not None:
        profile *= np.clip(np.nan_to_num(c.normals @ light_direction), 0.0, None)
    smooth = gaussian_filter1d(profile, max(smoothing_px, 1e-6) / step, axis=1,
                               mode="constant", truncate=4.0)
    peak = np.argmax(smooth, axis=1)
    rows = np.nonzero((peak > 0) & (peak < m - 1) & np.isfinite(c.dist[:, m // 2]))[0]
    y0, y1, y2 = (smooth[rows, peak[rows] + j] for j in (-1, 0, 1))
    den = y0 - 2 * y1 + y2
    frac = np.where(den < 0, 0.5 * (y0 - y2) / np.where(den < 0, den, -1.0), 0.0)
    ridge = c.q[rows] + ((c.u[peak[rows]] + frac * step)[:, None]) * c.normal[rows]
    seen = undistort_to_rays(ridge, geometry.camera_matrix, geometry.dist_coeffs)
    pts3 = intersect_plane(seen, geometry.plane_normal, geometry.plane_d)
    e1, e2 = orthonormal_basis(geometry.axis_direction)
    sec = np.column_stack([pts3 @ e1, pts3 @ e2])
    radial = np.full(k, np.nan)
    radial[rows] = np.hypot(*(sec - center).T) - radius
    return radial


def _plane_distance_on_cylinder(rays_xy: np.ndarray, center: np.ndarray, radius: float,
                                geometry: RigGeometry) -> tuple[np.ndarray, np.ndarray]:
    """Signed distance from the light plane of each ray's first hit on the cylinder, mm (NaN
    for a ray that misses), and the surface normal there."""
    e1, e2 = orthonormal_basis(geometry.axis_direction)
    a = geometry.axis_direction / np.linalg.norm(geometry.axis_direction)
    _, hit, normals = first_hit_on_cylinder(rays_xy, center[0] * e1 + center[1] * e2, a,
                                            radius)
    return hit @ geometry.plane_normal - geometry.plane_d, normals


def light_plane_directions(geometry: RigGeometry) -> tuple[np.ndarray, np.ndarray]:
    """An orthonormal basis (u1, u2) of the directions within the light plane, u1 along the
    section's first axis as far as the plane allows (the same for every frame of a
    calibration: kept)."""
    key = tuple(float(v) for v in (*geometry.axis_direction, *geometry.plane_normal))
    return _light_plane_directions(key)


@functools.lru_cache(maxsize=16)
def _light_plane_directions(key: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
    e1, _ = orthonormal_basis(np.array(key[:3]))
    n = np.array(key[3:]) / np.linalg.norm(key[3:])
    u1 = e1 - (e1 @ n) * n
    u1 /= np.linalg.norm(u1)
    return u1, np.cross(n, u1)


def _section_to_plane(geometry: RigGeometry) -> np.ndarray:
    """``[[e1 . u1, e1 . u2], [e2 . u1, e2 . u2]]``: the section's axes in the light plane's
    (a surface normal ``rel_x e1 + rel_y e2`` has ``normal . u = rel . (e1 . u, e2 . u)``)."""
    return _section_to_plane_of(tuple(float(v) for v in (*geometry.axis_direction,
                                                        *geometry.plane_normal)))


@functools.lru_cache(maxsize=16)
def _section_to_plane_of(key: tuple[float, ...]) -> np.ndarray:
    e1, e2 = orthonormal_basis(np.array(key[:3]))
    u1, u2 = _light_plane_directions(key)
    out = np.array([[e1 @ u1, e1 @ u2], [e2 @ u1, e2 @ u2]])
    out.flags.writeable = False
    return out


def light_direction(section: np.ndarray, center: np.ndarray, brightness: np.ndarray,
                    geometry: RigGeometry) -> np.ndarray | None:
    """Direction toward the laser (unit, camera frame) from the stripe's brightness along the
    arc.

    The laser's rays lie in the light plane, and a lit surface is as bright as the cosine of
    their incidence: ``brightness_i ~ N_i . v`` with ``N_i`` the surface normal and ``v`` in
    the plane, a linear least-squares problem in two unknowns. The source is taken as far
    away compared with the section (its direction the same over the arc). None when the
    points do not fix it (too few, or brightness that does not follow any direction).
    """
    u1, u2 = light_plane_directions(geometry)
    c0, c1, n, facing = sheet_kernels.light_coefficients(
        np.ascontiguousarray(section, np.float64), float(center[0]), float(center[1]),
        np.asarray(brightness, np.float64), _section_to_plane(geometry))
    v = c0 * u1 + c1 * u2
    norm = math.sqrt(float(v @ v))
    if n < 10 or not norm > 0 or not np.isfinite(norm):
        return None
    # Every point seen lit must face the source.
    return v / norm if facing > 0.9 else None


def sheet_sigma_from_profile(peak: np.ndarray, curvature: np.ndarray, slope_mm_per_px: np.ndarray,
                             filter_px: float, blur_px: float, groups: int = 12) -> float:
    """The sheet's thickness (Gaussian sigma, mm) from the stripe's profile at its centres.

    At each centre the extractor's smoothed profile has height ``peak`` and curvature
    ``curvature`` across the stripe; for a Gaussian line of image width ``w`` (lens blur
    included) seen with filters of scale ``s`` their ratio is ``w^2 + s^2``. A ratio per point
    is inflated by the noise in the curvature (the mean of 1/x exceeds 1/mean), so the ratio is
    taken of sums over ``groups`` runs of consecutive points (in arc order), and without blur
    the width is ``sigma / slope``, ``slope_mm_per_px`` the model's distance from the plane per
    pixel. Median over the groups; NaN when no group gives a width.
    """
    return float(sheet_kernels.profile_sigma(
        np.asarray(peak, np.float64), np.asarray(curvature, np.float64),
        np.asarray(slope_mm_per_px, np.float64), groups, filter_px**2 + blur_px**2))
