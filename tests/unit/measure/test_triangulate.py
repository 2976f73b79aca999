"""Triangulation and projection against known 3-D points."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from service.measure.section import (
    light_plane_coordinates,
    orthonormal_basis,
    project_to_section,
)
from service.measure.triangulate import intersect_plane, triangulate, undistort_to_rays

K = np.array([[3875.97, 0.0, 691.5], [0.0, 3876.75, 509.0], [0.0, 0.0, 1.0]])
DIST = np.array([-0.12, 0.25, 0.0004, -0.0003, 0.0])


def plane(normal: list[float], d: float) -> tuple[np.ndarray, float]:
    n = np.array(normal, float)
    return n / np.linalg.norm(n), d


def test_points_on_the_plane_round_trip_through_the_image_to_a_nanometre() -> None:
    rng = np.random.default_rng(1)
    n, d = plane([0.82, 0.02, 0.57], 171.0)
    # Random points on the plane around 300 mm in front of the camera.
    e1, e2 = orthonormal_basis(n)
    anchor = np.array([0.0, 0.0, d / n[2]])  # where the plane crosses the optical axis
    pts = anchor + rng.uniform(-40, 40, (500, 1)) * e1 + rng.uniform(-30, 30, (500, 1)) * e2
    pts = pts[pts[:, 2] > 50]
    img, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), K, DIST)
    back = triangulate(img.reshape(-1, 2), K, DIST, n, d)
    assert np.max(np.linalg.norm(back - pts, axis=1)) < 1e-6


def test_undistortion_inverts_projection_at_the_corners() -> None:
    rays = np.array([[-0.18, -0.13], [0.18, 0.13], [0.0, 0.0], [0.1, -0.12]])
    pts3 = np.column_stack([rays, np.ones(len(rays))])
    img, _ = cv2.projectPoints(pts3, np.zeros(3), np.zeros(3), K, DIST)
    assert np.allclose(undistort_to_rays(img.reshape(-1, 2), K, DIST), rays, atol=1e-10)


def test_ray_parallel_to_plane_or_behind_camera_is_nan() -> None:
    n, d = plane([1.0, 0.0, 0.0], 10.0)
    out = intersect_plane(np.array([[0.0, 0.3], [-1.0, 0.0], [1.0, 0.0]]), n, d)
    assert np.isnan(out[0]).all()   # parallel: x = 0 for every point of the ray
    assert np.isnan(out[1]).all()   # meets the plane behind the camera
    assert out[2] == pytest.approx([10.0, 0.0, 10.0])


def test_empty_input() -> None:
    assert undistort_to_rays(np.empty((0, 2)), K, DIST).shape == (0, 2)


@pytest.mark.parametrize("direction", [[1, 0, 0], [0, 0, 1], [0.3, -0.8, 0.5], [0, 1, 1e-9]])
def test_orthonormal_basis(direction: list[float]) -> None:
    a = np.array(direction, float)
    a /= np.linalg.norm(a)
    e1, e2 = orthonormal_basis(a)
    m = np.vstack([e1, e2, a])
    assert np.allclose(m @ m.T, np.eye(3), atol=1e-12)
    assert np.allclose(np.cross(e1, e2), a, atol=1e-12)


def test_projection_along_axis_maps_a_cylinder_to_a_circle() -> None:
    rng = np.random.default_rng(2)
    a = np.array([0.999, 0.004, 0.03])
    a /= np.linalg.norm(a)
    p0 = np.array([-2.1, 1.3, 297.4])
    e1, e2 = orthonormal_basis(a)
    t = rng.uniform(0, 2 * np.pi, 300)
    s = rng.uniform(-50, 50, 300)   # anywhere along the shaft
    pts = p0 + 12.5 * (np.cos(t)[:, None] * e1 + np.sin(t)[:, None] * e2) + s[:, None] * a
    sec = project_to_section(pts, a)
    centre = project_to_section(p0[None], a)[0]
    assert np.allclose(np.linalg.norm(sec - centre, axis=1), 12.5, atol=1e-9)


def test_light_plane_coordinates_preserve_distances() -> None:
    rng = np.random.default_rng(3)
    n = np.array([0.8, -0.1, 0.59])
    n /= np.linalg.norm(n)
    e1, e2 = orthonormal_basis(n)
    pts = 100 * n + rng.normal(size=(50, 1)) * e1 + rng.normal(size=(50, 1)) * e2
    uv = light_plane_coordinates(pts, n, np.array([1.0, 0.0, 0.0]))
    d3 = np.linalg.norm(pts[:, None] - pts[None], axis=2)
    d2 = np.linalg.norm(uv[:, None] - uv[None], axis=2)
    assert np.allclose(d2, d3, atol=1e-9)
