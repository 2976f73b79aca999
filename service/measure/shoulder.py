"""Two diameters in one frame: a shoulder under the laser.

Where the light sheet crosses a shoulder (a step between two diameters of a stepped shaft),
the stripe runs on one diameter over part of its arc and on the other over the rest. The
consensus of the circle (``diameter.on_the_shaft``) keeps the larger share and sets the other
aside (or, for a small step, keeps both), and the fit would then report one of the two, or
a blend, from a frame that shows both. Such a frame is refused, never averaged and never
taken for either.

A shoulder, as against scattered outliers, a reflection beside the stripe or a surface's form:
along the arc, the radii of the stripe's points keep one value over one side and another, a
step away, over the rest, each side tight about its own.

Pure: section points in, a reason out ("" for none). Lengths in mm.
"""

from __future__ import annotations

import numpy as np

MIN_SHARE = 0.1
"""The share of the stripe's points each diameter must hold (fewer: the stripe's end)."""
MIN_STEP_MM = 0.05
"""The least step of radius between the two (smaller: the form, a run-out, the scatter)."""
MAX_SPREAD = 0.25
"""Each side's scatter of radius (robust sigma) at most this share of the step..."""
MAX_SPREAD_MM = 0.03
"""... and at most this (a surface's points scatter by micrometres; a lit machine part or a
line in the background, set aside by the circle's consensus, by millimetres)."""


def second_diameter(section_mm: np.ndarray, center_mm: np.ndarray) -> str:
    """Why the section shows two diameters ("" when it does not).

    The points' radii about ``center_mm``, in their order along the arc, are split where the
    two sides differ most (a change point); a shoulder when each side holds ``MIN_SHARE`` of
    the points, the step between their medians is ``MIN_STEP_MM`` or more, and each side is
    tight about its own median (``MAX_SPREAD`` of the step).

    Parameters
    ----------
    section_mm : ndarray, shape (N, 2)
        Every point of the stripe on the section plane, mm.
    center_mm : ndarray, shape (2,)
        The centre of the circle the points were taken for, mm (the surface's own).

    Returns
    -------
    str
        The reason naming both diameters, or "".
    """
    pts = np.asarray(section_mm, float)
    n = len(pts)
    least = max(int(np.ceil(MIN_SHARE * n)), 3)
    if n < 2 * least:
        return ""
    rel = pts - np.asarray(center_mm, float)
    mean = rel.mean(axis=0)
    angle = np.arctan2(rel[:, 1], rel[:, 0]) - np.arctan2(mean[1], mean[0])
    angle = (angle + np.pi) % (2.0 * np.pi) - np.pi  # along the arc, from its middle
    radii = np.hypot(rel[:, 0], rel[:, 1])[np.argsort(angle)]
    csum = np.cumsum(radii)
    k = np.arange(least, n - least + 1)
    left = csum[k - 1] / k
    right = (csum[-1] - csum[k - 1]) / (n - k)
    split = int(k[np.argmax(k * (n - k) * (left - right) ** 2)])
    a, b = radii[:split], radii[split:]
    ra, rb = float(np.median(a)), float(np.median(b))
    step = abs(rb - ra)
    spread = 1.4826 * max(float(np.median(np.abs(a - ra))), float(np.median(np.abs(b - rb))))
    if step < MIN_STEP_MM or spread > min(MAX_SPREAD * step, MAX_SPREAD_MM):
        return ""
    return (f"two diameters in one frame, {2.0 * ra:.3f} and {2.0 * rb:.3f} mm, over "
            f"{100.0 * split / n:.0f} and {100.0 * (n - split) / n:.0f} % of the stripe: a "
            "shoulder under the laser (refused, never taken for either)")
