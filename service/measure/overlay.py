"""The latest frame as an operator sees it: the stripe centres that entered the fit and the
fitted section drawn back onto the image (pure: arrays in, an image out)."""

from __future__ import annotations

import cv2
import numpy as np

from service.measure.geometry import RigGeometry
from service.measure.result import Measurement
from service.measure.section import section_circle_on_plane

STRIPE_BGR = (60, 220, 60)
SECTION_BGR = (40, 60, 255)


def on_sensor(image: np.ndarray, origin: tuple[int, int] | None,
              sensor_size: tuple[int, int]) -> np.ndarray:
    """A region of the sensor (``origin`` its top-left, px) placed on a black frame of the
    whole sensor (``sensor_size``: width, height), so that sensor positions draw where they
    belong; the image itself when it is a whole frame."""
    if origin is None:
        return image
    w, h = sensor_size
    canvas = np.zeros((h, w), image.dtype)
    x0, y0 = origin
    part = image[:max(0, h - y0), :max(0, w - x0)]
    canvas[y0:y0 + part.shape[0], x0:x0 + part.shape[1]] = part
    return canvas


def draw_overlay(image: np.ndarray, m: Measurement | None, geometry: RigGeometry | None,
                 width: int | None = None) -> np.ndarray:
    """A BGR picture of ``image`` (8 or 16 bit grey) with the measurement drawn over it.

    Parameters
    ----------
    image : ndarray, shape (H, W)
        The frame as the camera sent it.
    m : Measurement or None
        Its measurement: the stripe points in green, and for a good one the fitted section
        (where a cylinder of that centre and diameter meets the light plane) in red.
    geometry : RigGeometry or None
        The calibration it was measured with (needed for the section).
    width : int or None
        Scale the picture to this width, px (None: full size).
    """
    grey = image if image.dtype == np.uint8 else (image >> 8).astype(np.uint8)
    # Stretch a dark frame so the shaft is visible; the stripe saturates anyway.
    top = float(np.percentile(grey, 99.5)) or 1.0
    out = cv2.cvtColor(cv2.convertScaleAbs(grey, alpha=min(4.0, 255.0 / top)),
                       cv2.COLOR_GRAY2BGR)
    scale = 1.0 if not width else width / image.shape[1]
    if scale != 1.0:
        out = cv2.resize(out, (int(width), round(image.shape[0] * scale)),
                         interpolation=cv2.INTER_AREA)
    if m is None:
        return out
    pts = np.asarray(m.points_px, np.float64).reshape(-1, 2) * scale
    for x, y in pts[:: max(1, len(pts) // 400)]:
        cv2.circle(out, (round(x), round(y)), 1, STRIPE_BGR, -1)
    if m and geometry is not None and m.center_mm is not None and m.diameter_mm:
        curve = section_circle_on_plane(m.center_mm, m.diameter_mm / 2.0,
                                        geometry.axis_direction, geometry.plane_normal,
                                        geometry.plane_d)
        curve = curve[curve[:, 2] > 1.0]
        if len(curve):
            px, _ = cv2.projectPoints(curve, np.zeros(3), np.zeros(3), geometry.camera_matrix,
                                      geometry.dist_coeffs)
            poly = np.round(px.reshape(-1, 2) * scale).astype(np.int32)
            cv2.polylines(out, [poly], True, SECTION_BGR, 1, cv2.LINE_8)
    return out
