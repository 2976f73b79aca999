"""The speckle floor: how much a frame's diameter scatters from the speckle alone, whatever
the extractor.

Speckle multiplies the stripe's light by a grainy field. Across the stripe a grain's slope
tilts the profile, and a Gaussian profile times a ramp is the same Gaussian moved by its
width squared times the ramp's slope: the stripe's light itself has moved, and no estimator
of its centre can tell that from the surface having moved (a finer one only adds its own
error). This module measures that movement on the simulator's own noise-free light, per
stripe centre: the shift of the profile's centroid (over four of its widths either side)
between the speckled and the unspeckled light of a frame, along the centre's normal,
triangulated and projected as the measurement does, and averaged over the arc with the best
weights the row's frames show (each point by the inverse of its shift's variance over the
other half of the frames). The scatter of that average from frame to frame is the floor: an
extractor on these frames scatters about as much or more.

Pure analysis of rendered light; used by ``tests.bench.rig_range``.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy.ndimage import map_coordinates

from drivers.sim.rig import ShaftRenderer
from service.measure.diameter import (
    MeasureParams,
    axis_center,
    drop_grazing,
    on_the_shaft,
    section_points,
)
from service.measure.geometry import geometry_of
from service.measure.stripe import extract_stripe


def diameter_shifts_um(renderer: ShaftRenderer, diameter_mm: float, frames: int
                       ) -> np.ndarray:
    """Per frame and stripe centre, the radial shift (um of radius) the frame's speckle
    gives the centroid of the stripe's light; shape (frames, centres)."""
    geometry = geometry_of(renderer.calibration)
    params = MeasureParams()
    center = axis_center(geometry)
    known = (center, 1e-5)
    clean, (x0, y0) = renderer.stripe_light(diameter_mm)
    found = extract_stripe(np.clip(renderer.render_clean(diameter_mm) + 5.0, 0.0, 255.0),
                           params.stripe)
    points = drop_grazing(on_the_shaft(section_points(found, geometry), params, known),
                          geometry, params, center)
    st = points.stripe
    moved = section_points(replace(st, xy=st.xy + st.normal), geometry).section
    mm_per_px = np.hypot(*(moved - center).T) - np.hypot(*(points.section - center).T)
    reach = 4.0 * max(float(np.median(st.width_px)), 1.0)
    t = np.arange(-reach, reach + 1e-9, 0.1)
    cols = (st.xy[:, :1] - x0) + t * st.normal[:, :1]
    rows = (st.xy[:, 1:] - y0) + t * st.normal[:, 1:]

    def centroid(light: np.ndarray) -> np.ndarray:
        v = map_coordinates(light, [rows.ravel(), cols.ravel()], order=1).reshape(cols.shape)
        return (v * t).sum(axis=1) / np.maximum(v.sum(axis=1), 1e-12)

    base = centroid(clean)
    return np.array([(centroid(renderer.stripe_light(diameter_mm, i)[0]) - base) * mm_per_px
                     for i in range(frames)]) * 1e3


def floor_um(shifts_um: np.ndarray) -> np.ndarray:
    """Per frame, the diameter's shift (um) from ``diameter_shifts_um``'s radial shifts,
    averaged over the arc with each centre weighted by the inverse of its shift's variance,
    estimated on the other half of the frames (weights and shifts from the same frames
    would flatter the floor)."""
    halves = np.array_split(np.arange(len(shifts_um)), 2)
    out = np.empty(len(shifts_um))
    for mine, other in (halves, halves[::-1]):
        var = shifts_um[other].var(axis=0)
        w = 1.0 / np.maximum(var, 1e-6 * max(float(var.max()), 1e-30))
        out[mine] = 2.0 * (shifts_um[mine] * w).sum(axis=1) / w.sum()
    return out
