"""The spindle axis from the board clamped between the lathe centres at several rotations
(paper Appendix A, generalised as paper-notes.md item 8)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from service.calibrate.board import Board
from service.calibrate.plane import board_plane


@dataclass(frozen=True)
class AxisResult:
    """Axis direction and a point on it, with residuals, or why there are none."""

    direction: np.ndarray | None
    point: np.ndarray | None = None
    rotation_span_deg: float = 0.0
    plane_residual_mm: float = math.nan   # RMS distance of the axis line from the board planes
    poses: int = 0
    rejected: dict[int, str] = field(default_factory=dict)
    reason: str = ""

    def __bool__(self) -> bool:
        return self.direction is not None and not self.reason


def axis_from_planes(normals: np.ndarray, offsets: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, float]:
    """Line common to planes ``n_i . X = d_i``: direction (smallest eigenvector of
    ``sum n n^T``), the point on it closest to the origin (least squares), RMS residual."""
    m = normals.T @ normals
    _, v = np.linalg.eigh(m)  # ascending eigenvalues
    direction = v[:, 0]
    point, *_ = np.linalg.lstsq(normals, offsets, rcond=None)
    point = point - (point @ direction) * direction  # the line's point closest to the origin
    residual = float(np.sqrt(np.mean((normals @ point - offsets) ** 2)))
    return direction, point, residual


def calibrate_axis(images: list[np.ndarray], board: Board, K: np.ndarray, dist: np.ndarray,
                   light_plane: tuple[np.ndarray, float] | None = None, min_poses: int = 3,
                   min_span_deg: float = 30.0) -> AxisResult:
    """Spindle axis from images of the board turned about it.

    With the light plane, the returned point is where the axis crosses it (the section the
    gauge measures); otherwise the point closest to the camera. Refuses fewer than
    ``min_poses`` poses or a rotation span below ``min_span_deg``.
    """
    normals, offsets, rejected = [], [], {}
    for i, im in enumerate(images):
        p = board_plane(im, board, K, dist)
        if isinstance(p, str):
            rejected[i] = p
            continue
        normals.append(p.normal)
        offsets.append(p.d)
    if len(normals) < min_poses:
        return AxisResult(None, poses=len(normals), rejected=rejected, reason=(
            f"the board was found at {len(normals)} rotations, need {min_poses}: turn the "
            "spindle by 15-30 degrees between images, keeping the board in view"))
    n = np.array(normals)
    span = max(math.degrees(math.acos(min(1.0, abs(float(a @ b))))) for a in n for b in n)
    if span < min_span_deg:
        return AxisResult(None, rotation_span_deg=span, poses=len(n), rejected=rejected,
                          reason=f"the board turned through only {span:.1f} degrees: turn it "
                          f"through at least {min_span_deg:.0f}")
    direction, point, residual = axis_from_planes(n, np.array(offsets))
    if light_plane is not None:
        pn, pd = light_plane
        denom = float(pn @ direction)
        if abs(denom) > 1e-6:
            point = point + ((pd - pn @ point) / denom) * direction
    return AxisResult(direction, point, span, residual, len(n), rejected)
