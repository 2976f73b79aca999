"""The sheet-thickness correction of a fitted section, with the model's answers kept.

``service.measure.sheet`` predicts the radial error the light sheet's thickness leaves at
points along the arc by casting rays across the stripe: a millisecond or two of numerics.
That error depends on the calibration, the section circle, the arc, the sheet's thickness and
the laser's direction, all of which change slowly or not at all from frame to frame, so the
model is evaluated on a grid of those (centre and radius to 10 um, at fixed angles 0.05 rad
apart over the arc widened to 0.1 rad steps, the light's direction to 0.01 rad, the
thickness at nodes 2.5 % apart with linear interpolation between them) and its answers are
kept: a new shaft, a new calibration or a moved arc evaluates it again. The fitted radius
stays within 20 nm of the model evaluated densely at the fitted circle itself
(``tests/unit/measure/test_sheet.py``; measured 14 nm).
"""

from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Callable, Hashable
from typing import Any

import numpy as np

from service.measure.geometry import RigGeometry
from service.measure.params import MeasureParams
from service.measure.section import SectionPoints
from service.measure.sheet import (
    Crossings,
    arc_angles,
    cross_the_stripe,
    light_direction,
    light_plane_directions,
    ridge_bias,
    sheet_sigma_from_profile,
)

SAMPLE_STEP_RAD = 0.05
"""Spacing of the points along the arc where the sheet's error is modelled (it changes slowly
along it): a fixed grid, so that frames whose stripes end a little differently share it."""

POSITION_STEP_MM = 0.01
ARC_END_STEP_RAD = 0.1
LIGHT_STEP_RAD = 0.01
SIGMA_STEP = 0.025


class _Kept:
    """A bounded store of computed answers, least recently used dropped first."""

    def __init__(self, size: int) -> None:
        self._size = size
        self._items: OrderedDict[Hashable, Any] = OrderedDict()

    def get(self, key: Hashable, make: Callable[[], Any]) -> Any:
        if key in self._items:
            self._items.move_to_end(key)
            return self._items[key]
        value = self._items[key] = make()
        if len(self._items) > self._size:
            self._items.popitem(last=False)
        return value


_CROSSINGS = _Kept(64)
_RIDGES = _Kept(512)


def correct_sheet_bias(points: SectionPoints, center: np.ndarray, radius: float,
                       geometry: RigGeometry, params: MeasureParams) -> np.ndarray:
    """The section coordinates (mm) moved radially by the error the sheet's thickness leaves
    in them, modelled on a fitted section of ``center`` (mm) and ``radius`` (mm)
    (``service.measure.sheet``).

    Points where the model has no answer (the camera does not see across the stripe there)
    are left where they are; so are all when the stripe gives no heights or no width.
    """
    st = points.stripe
    if st.peak is None:
        return points.section
    center = np.asarray(center, np.float64)
    angles, _ = arc_angles(points.section, center)
    blur, filter_px = params.stripe.optics_blur_px, st.filter_px
    smoothing = float(np.hypot(filter_px, blur))
    gkey = geometry.key
    c_q = tuple(round(float(v) / POSITION_STEP_MM) for v in center)
    r_q = round(float(radius) / POSITION_STEP_MM)
    lo_q = math.floor(float(angles.min()) / ARC_END_STEP_RAD)
    hi_q = math.ceil(float(angles.max()) / ARC_END_STEP_RAD)
    model_center = np.array(c_q, np.float64) * POSITION_STEP_MM
    model_radius = r_q * POSITION_STEP_MM
    per_end = round(ARC_END_STEP_RAD / SAMPLE_STEP_RAD)
    samples = np.arange(lo_q * per_end, hi_q * per_end + 1) * SAMPLE_STEP_RAD
    ckey = (gkey, c_q, r_q, lo_q, hi_q, smoothing)
    crossings: Crossings = _CROSSINGS.get(ckey, lambda: cross_the_stripe(
        model_center, model_radius, samples, geometry, smoothing))
    order = np.argsort(angles)  # the points in arc order, for the light and the width
    # The laser's irradiance: the smoothed height of a Gaussian line of width w, seen with
    # filters of scale s, is its height times w / sqrt(w^2 + s^2).
    with np.errstate(divide="ignore", invalid="ignore"):
        brightness = st.peak * np.sqrt(st.width_px**2 + filter_px**2) / st.width_px
    toward_laser = light_direction(points.section, center, brightness, geometry)
    light_q = None
    if toward_laser is not None:
        u1, u2 = light_plane_directions(geometry)
        light_q = round(math.atan2(float(toward_laser @ u2), float(toward_laser @ u1))
                        / LIGHT_STEP_RAD)
        a = light_q * LIGHT_STEP_RAD
        toward_laser = math.cos(a) * u1 + math.sin(a) * u2
    sigma = params.sheet_sigma_mm
    if sigma is None:
        slope = np.interp(angles, samples, crossings.slope_mm_per_px)
        sigma = sheet_sigma_from_profile(st.peak[order], st.strength[order], slope[order],
                                         filter_px, blur)
    if not (np.isfinite(sigma) and sigma > 0):
        return points.section
    # The thickness between two nodes of a geometric grid; the error interpolated between.
    pos = math.log(sigma) / math.log1p(SIGMA_STEP)
    node = math.floor(pos)
    frac = pos - node

    def ridge_at(k: int) -> np.ndarray:
        s_k = (1.0 + SIGMA_STEP) ** k
        return _RIDGES.get((ckey, light_q, k), lambda: ridge_bias(
            crossings, geometry, model_center, model_radius, s_k, smoothing, toward_laser))

    radial = (1.0 - frac) * ridge_at(node) + frac * ridge_at(node + 1)
    known = np.isfinite(radial)
    if known.sum() < 2:
        return points.section
    dr = np.interp(angles, samples[known], radial[known])
    rel = points.section - center
    dist = np.maximum(np.hypot(rel[:, 0], rel[:, 1]), 1e-300)
    return center + rel * ((dist - dr) / dist)[:, None]
