"""Compiled inner loops of the sheet model's per-frame estimates (numba): the laser's
direction from the stripe's brightness and the sheet's thickness from its profile
(``service.measure.sheet`` is the interface and the documentation). No I/O."""

from __future__ import annotations

import math

import numba
import numpy as np

_OPTS = dict(cache=True, nogil=True)


@numba.njit(**_OPTS)
def light_coefficients(section: np.ndarray, cx: float, cy: float, brightness: np.ndarray,
                       basis: np.ndarray) -> tuple[float, float, int, float]:
    """Least squares of ``brightness_i = (rel_i @ basis) . c`` over the points with a finite,
    positive brightness, ``rel_i`` the unit radial direction of point i about (cx, cy).

    Returns ``c`` (two numbers), how many points took part, and the share of them whose
    ``rel_i @ basis`` points the way of ``c`` (they face the source).
    """
    n_all = section.shape[0]
    p = np.empty(n_all)   # the unit radial direction of each point, in the basis
    q = np.empty(n_all)
    use = np.zeros(n_all, np.bool_)
    a00 = a01 = a11 = r0 = r1 = 0.0
    n = 0
    for i in range(n_all):
        b = brightness[i]
        if not (math.isfinite(b) and b > 0.0):
            continue
        dx, dy = section[i, 0] - cx, section[i, 1] - cy
        d = max(math.sqrt(dx * dx + dy * dy), 1e-300)  # mm: no overflow
        p[i] = (dx * basis[0, 0] + dy * basis[1, 0]) / d
        q[i] = (dx * basis[0, 1] + dy * basis[1, 1]) / d
        use[i] = True
        a00 += p[i] * p[i]
        a01 += p[i] * q[i]
        a11 += q[i] * q[i]
        r0 += p[i] * b
        r1 += q[i] * b
        n += 1
    det = a00 * a11 - a01 * a01
    if n < 2 or det == 0.0:
        return 0.0, 0.0, n, 0.0
    c0 = (a11 * r0 - a01 * r1) / det
    c1 = (a00 * r1 - a01 * r0) / det
    facing = 0
    for i in range(n_all):
        if use[i] and p[i] * c0 + q[i] * c1 > 0.0:
            facing += 1
    return c0, c1, n, facing / n


@numba.njit(**_OPTS)
def profile_sigma(peak: np.ndarray, curvature: np.ndarray, slope: np.ndarray, groups: int,
                  smoothing2: float) -> float:
    """``sheet.sheet_sigma_from_profile`` compiled: the median over runs of consecutive valid
    points (np.array_split's runs) of ``sqrt(sum peak / sum curvature - smoothing2)`` times
    the run's median slope; NaN when no run gives a width."""
    n = peak.shape[0]
    idx = np.empty(n, np.int64)
    m = 0
    for i in range(n):
        if (math.isfinite(peak[i]) and math.isfinite(curvature[i]) and curvature[i] > 0.0
                and math.isfinite(slope[i])):
            idx[m] = i
            m += 1
    runs = max(1, min(groups, m // 5))
    if m < runs or m == 0:
        return math.nan
    size, extra = m // runs, m % runs
    sigmas = np.empty(runs)
    k = 0
    start = 0
    for g in range(runs):
        length = size + (1 if g < extra else 0)
        sp = sc = 0.0
        slopes = np.empty(length)
        for j in range(length):
            i = idx[start + j]
            sp += peak[i]
            sc += curvature[i]
            slopes[j] = slope[i]
        start += length
        w2 = sp / sc - smoothing2
        if w2 > 0.0:
            sigmas[k] = math.sqrt(w2) * np.median(slopes)
            k += 1
    return np.median(sigmas[:k]) if k > 0 else math.nan


@numba.njit(**_OPTS)
def arc_angles(section: np.ndarray, cx: float, cy: float) -> tuple[np.ndarray, float]:
    """``sheet.arc_angles`` compiled: the points' angles about (cx, cy) unwrapped about the
    arc's middle (the mean direction), and that middle, radians."""
    n = section.shape[0]
    ang = np.empty(n)
    s = c = 0.0
    for i in range(n):
        a = math.atan2(section[i, 1] - cy, section[i, 0] - cx)
        ang[i] = a
        s += math.sin(a)
        c += math.cos(a)
    mid = math.atan2(s / max(n, 1), c / max(n, 1))
    for i in range(n):
        ang[i] = mid + (ang[i] - mid + math.pi) % (2.0 * math.pi) - math.pi
    return ang, mid
