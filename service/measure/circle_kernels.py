"""Compiled circle fitting (numba): Levenberg-Marquardt with the analytic Jacobian, the robust
fit-and-reject rounds of ``fit.fit_geometric`` and ``fit.fit_axis_prior``, and the covariance.

``service.measure.fit`` is the interface (validation, results, documentation); this module is
its inner loops, written once in compiled form because a frame runs them a dozen times on a
few hundred points and numpy's per-call overhead (a median is ~15 us however short the array)
was most of their cost. Pure numerics; no I/O.
"""

from __future__ import annotations

import math

import numba
import numpy as np

_OPTS = dict(cache=True, nogil=True)
# Sums over the points may be reassociated (vectorised); NaN and infinity keep their meaning
# (a diverging trial step must still compare as worse).
_SUMS = dict(_OPTS, fastmath={"reassoc", "contract", "arcp"})
MAD_TO_SIGMA = 1.4826
# Distances here are millimetres: sqrt(dx^2 + dy^2) cannot overflow, and costs a third of the
# overflow-safe hypot in the fits' inner loops.


@numba.njit(**_OPTS)
def _dist(x: np.ndarray, y: np.ndarray, cx: float, cy: float) -> np.ndarray:
    """Distance of each point (x, y) from (cx, cy)."""
    out = np.empty(x.shape[0])
    for i in range(x.shape[0]):
        dx, dy = x[i] - cx, y[i] - cy
        out[i] = math.sqrt(dx * dx + dy * dy)
    return out


@numba.njit(**_OPTS)
def solve_circle(x: np.ndarray, y: np.ndarray, w: np.ndarray, cx: float, cy: float, r: float,
                 c0x: float, c0y: float, inv_s2: float, max_iter: int = 100,
                 tol: float = 1e-12) -> tuple[float, float, float, bool]:
    """Minimise ``sum w_i (|p_i - c| - r)^2 + inv_s2 |c - c0|^2`` over (cx, cy, r) from the
    given start by Levenberg-Marquardt (Marquardt's diagonal scaling). Returns the solution
    and whether it is a circle (finite, positive radius)."""
    q = np.array([cx, cy, r])
    jtj = np.zeros((3, 3))
    grad = np.zeros(3)
    cost = _normal_equations(x, y, w, q, c0x, c0y, inv_s2, jtj, grad)
    t_jtj = np.zeros((3, 3))
    t_grad = np.zeros(3)
    lam = 1e-9
    for _ in range(max_iter):
        a = jtj.copy()
        for i in range(3):
            a[i, i] += lam * jtj[i, i]
        step = _solve3(a, -grad)
        trial = q + step
        t_cost = _normal_equations(x, y, w, trial, c0x, c0y, inv_s2, t_jtj, t_grad)
        small = True
        for i in range(3):
            if abs(step[i]) > tol * (abs(trial[i]) + tol):
                small = False
        small = small or (t_cost <= cost and cost - t_cost <= 1e-15 * cost)
        if t_cost <= cost or (small and t_cost <= cost * (1.0 + 1e-12)):
            q[:] = trial
            cost = t_cost
            jtj[:, :] = t_jtj
            grad[:] = t_grad
            lam *= 0.1
            if small:
                break
        else:
            lam *= 10.0
            if small or lam > 1e12:
                break  # no step lowers the cost: at the minimum to rounding
    ok = math.isfinite(q[0]) and math.isfinite(q[1]) and math.isfinite(q[2]) and q[2] > 0
    return q[0], q[1], q[2], ok


@numba.njit(**_SUMS)
def _normal_equations(x: np.ndarray, y: np.ndarray, w: np.ndarray, q: np.ndarray,
                      c0x: float, c0y: float, inv_s2: float, jtj: np.ndarray,
                      grad: np.ndarray) -> float:
    """Cost, J^T W J and the gradient J^T W r at q (the Jacobian's rows are -(ux, uy, 1))."""
    sxx = sxy = sx = syy = sy = sw = gx = gy = gr = cost = 0.0
    for i in range(x.shape[0]):
        dx, dy = x[i] - q[0], y[i] - q[1]
        dist = max(math.sqrt(dx * dx + dy * dy), 1e-300)
        res = dist - q[2]
        inv = 1.0 / dist
        ux, uy = dx * inv, dy * inv
        wi = w[i]
        sxx += wi * ux * ux
        sxy += wi * ux * uy
        syy += wi * uy * uy
        sx += wi * ux
        sy += wi * uy
        sw += wi
        gx += wi * res * ux
        gy += wi * res * uy
        gr += wi * res
        cost += wi * res * res
    dcx, dcy = q[0] - c0x, q[1] - c0y
    jtj[0, 0], jtj[0, 1], jtj[0, 2] = sxx + inv_s2, sxy, sx
    jtj[1, 0], jtj[1, 1], jtj[1, 2] = sxy, syy + inv_s2, sy
    jtj[2, 0], jtj[2, 1], jtj[2, 2] = sx, sy, sw
    grad[0] = -gx + inv_s2 * dcx
    grad[1] = -gy + inv_s2 * dcy
    grad[2] = -gr
    return cost + inv_s2 * (dcx * dcx + dcy * dcy)


@numba.njit(**_OPTS)
def _solve3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Solution of a 3x3 system by Gaussian elimination with partial pivoting."""
    m = a.copy()
    v = b.copy()
    for col in range(3):
        piv = col
        for row in range(col + 1, 3):
            if abs(m[row, col]) > abs(m[piv, col]):
                piv = row
        if piv != col:
            for k in range(3):
                m[col, k], m[piv, k] = m[piv, k], m[col, k]
            v[col], v[piv] = v[piv], v[col]
        for row in range(col + 1, 3):
            f = m[row, col] / m[col, col]
            for k in range(col, 3):
                m[row, k] -= f * m[col, k]
            v[row] -= f * v[col]
    out = np.zeros(3)
    for row in range(2, -1, -1):
        acc = v[row]
        for k in range(row + 1, 3):
            acc -= m[row, k] * out[k]
        out[row] = acc / m[row, row]
    return out


@numba.njit(**_OPTS)
def inverse3(a: np.ndarray) -> np.ndarray:
    """Inverse of a 3x3 matrix by its adjugate (infinities where it is singular): what
    ``np.linalg.inv`` gives, without its per-call overhead for an information matrix."""
    c00 = a[1, 1] * a[2, 2] - a[1, 2] * a[2, 1]
    c01 = a[1, 2] * a[2, 0] - a[1, 0] * a[2, 2]
    c02 = a[1, 0] * a[2, 1] - a[1, 1] * a[2, 0]
    det = a[0, 0] * c00 + a[0, 1] * c01 + a[0, 2] * c02
    out = np.empty((3, 3))
    if det == 0.0 or not math.isfinite(det):
        out[:, :] = np.inf
        return out
    out[0, 0] = c00 / det
    out[1, 0] = c01 / det
    out[2, 0] = c02 / det
    out[0, 1] = (a[0, 2] * a[2, 1] - a[0, 1] * a[2, 2]) / det
    out[1, 1] = (a[0, 0] * a[2, 2] - a[0, 2] * a[2, 0]) / det
    out[2, 1] = (a[0, 1] * a[2, 0] - a[0, 0] * a[2, 1]) / det
    out[0, 2] = (a[0, 1] * a[1, 2] - a[0, 2] * a[1, 1]) / det
    out[1, 2] = (a[0, 2] * a[1, 0] - a[0, 0] * a[1, 2]) / det
    out[2, 2] = (a[0, 0] * a[1, 1] - a[0, 1] * a[1, 0]) / det
    return out


@numba.njit(**_OPTS)
def order_along_arc(x: np.ndarray, y: np.ndarray, cx: float, cy: float) -> np.ndarray:
    """Indices that sort points by angle around (cx, cy), starting after the largest gap."""
    n = x.shape[0]
    ang = np.arctan2(y - cy, x - cx)
    order = np.argsort(ang)
    best, start = -1.0, 0
    for i in range(n):
        nxt = ang[order[i + 1]] if i + 1 < n else ang[order[0]] + 2 * math.pi
        gap = nxt - ang[order[i]]
        if gap > best:
            best, start = gap, (i + 1) % n
    out = np.empty(n, np.int64)
    for i in range(n):
        out[i] = order[(start + i) % n]
    return out


@numba.njit(**_OPTS)
def correlation_factor(residuals: np.ndarray, max_lag_fraction: float = 0.2) -> float:
    """``fit.correlation_factor`` compiled: ``tau = 1 + 2 sum rho_k`` while rho_k >= 0.05."""
    n = residuals.shape[0]
    r = residuals - residuals.mean()
    var = 0.0
    for i in range(n):
        var += r[i] * r[i]
    if n < 8 or var <= 0:
        return 1.0
    tau = 1.0
    for k in range(1, max(2, int(max_lag_fraction * n))):
        acc = 0.0
        for i in range(n - k):
            acc += r[i] * r[i + k]
        rho = acc / var
        if rho < 0.05:
            break
        tau += 2.0 * rho
    return tau


@numba.njit(**_OPTS)
def _mad(values: np.ndarray) -> tuple[float, float]:
    """Median and the robust standard deviation (scaled MAD) about it."""
    med = np.median(values)
    return med, MAD_TO_SIGMA * np.median(np.abs(values - med))


@numba.njit(**_OPTS)
def robust_rounds(x: np.ndarray, y: np.ndarray, sw_all: np.ndarray, cx: float, cy: float,
                  r: float, inliers: np.ndarray, with_prior: bool, c0x: float, c0y: float,
                  sigma: float, reject_k: float, max_rounds: int, floor_mm: float
                  ) -> tuple[float, float, float, np.ndarray, int]:
    """Fit-and-reject rounds of ``fit.fit_geometric`` (``with_prior`` False) and
    ``fit.fit_axis_prior`` (True), from the start (cx, cy, r) and ``inliers``.

    Returns the circle, the inliers it was fitted with, and a status: 0 done, 1 fewer than 3
    inliers left, 2 the fit did not converge. The points' order along the arc (for the
    correlation of the residuals) is taken once, about the start: the centre moves by
    micrometres between rounds.
    """
    inl = inliers.copy()
    order_all = order_along_arc(x, y, cx, cy) if with_prior else np.empty(0, np.int64)
    pos = np.empty(x.shape[0], np.int64)
    for k in range(max_rounds):
        last = k == max_rounds - 1
        idx = np.flatnonzero(inl)
        if idx.shape[0] < 3:
            return cx, cy, r, inl, 1
        ux, uy, usw = x[idx], y[idx], sw_all[idx]
        if with_prior:
            dist0 = _dist(ux, uy, cx, cy)
            res0 = (dist0 - np.median(dist0)) * usw
            for i in range(idx.shape[0]):
                pos[idx[i]] = i
            in_arc = np.empty(idx.shape[0])
            m = 0
            for j in order_all:
                if inl[j]:
                    in_arc[m] = res0[pos[j]]
                    m += 1
            noise = _mad(res0)[1]
            noise = max(noise, 1e-6) * math.sqrt(correlation_factor(in_arc))
            w = usw * usw / (noise * noise)
            cx, cy, r, ok = solve_circle(ux, uy, w, cx, cy, r, c0x, c0y, sigma ** -2.0)
        else:
            cx, cy, r, ok = solve_circle(ux, uy, usw * usw, cx, cy, r, 0.0, 0.0, 0.0)
        if not ok:
            return cx, cy, r, inl, 2
        res = (_dist(x, y, cx, cy) - r) * sw_all
        med, scale = _mad(res[idx])
        centre = med if with_prior else 0.0
        new = np.abs(res - centre) <= max(reject_k * scale, floor_mm)
        if np.array_equal(new, inl) or last:
            break  # the inliers reported are those this fit was made with
        inl = new
    return cx, cy, r, inl, 0


@numba.njit(**_OPTS)
def circle_information(x: np.ndarray, y: np.ndarray, cx: float, cy: float, r: float,
                       w: np.ndarray, n_free: int, use: np.ndarray, clip: float
                       ) -> np.ndarray:
    """``s^-2 J^T W J`` over the points ``use`` marks, with ``s^2`` their weighted residual
    variance inflated for correlation along the arc (``fit.circle_covariance``); the other
    points whose weighted residual lies within twice ``clip`` count in ``s^2`` at ``clip``
    (winsorized), those beyond it not at all."""
    n = x.shape[0]
    dx, dy = x - cx, y - cy
    dist = np.maximum(np.sqrt(dx * dx + dy * dy), 1e-300)
    counted = np.zeros(n, np.bool_)
    wres = np.zeros(n)
    s2 = 0.0
    n_use = 0
    for i in range(n):
        v = (dist[i] - r) * math.sqrt(w[i])
        if use[i]:
            n_use += 1
        elif clip < math.inf and abs(v) <= 2.0 * clip:
            v = clip if v > 0 else -clip
        else:
            continue
        counted[i] = True
        wres[i] = v
        s2 += v * v
    s2 /= max(n_use - n_free, 1)
    idx = np.flatnonzero(counted)
    order = order_along_arc(x[idx], y[idx], cx, cy)
    s2 *= correlation_factor(wres[idx][order])
    s2 = max(s2, 1e-30)
    info = np.zeros((3, 3))
    for i in range(n):
        if not use[i]:
            continue
        j = (-dx[i] / dist[i], -dy[i] / dist[i], -1.0)
        for a in range(3):
            for b in range(3):
                info[a, b] += w[i] * j[a] * j[b]
    return info / s2


@numba.njit(**_OPTS)
def arc_variance(x: np.ndarray, y: np.ndarray, cx: float, cy: float, use: np.ndarray,
                 res: np.ndarray, max_ratio: float) -> np.ndarray:
    """``fit.arc_variance`` compiled: exp of a quadratic in the angle about (cx, cy), fitted by
    least squares to log(res^2 + floor) over the points ``use`` marks, median 1 over them,
    within [1 / max_ratio, max_ratio]."""
    n = x.shape[0]
    ang = np.arctan2(y - cy, x - cx)
    s_sum, c_sum, m, r2_sum = 0.0, 0.0, 0, 0.0
    for i in range(n):
        if use[i]:
            s_sum += math.sin(ang[i])
            c_sum += math.cos(ang[i])
            r2_sum += res[i] * res[i]
            m += 1
    mid = math.atan2(s_sum, c_sum)
    floor = 0.01 * r2_sum / max(m, 1) + 1e-30
    half = 1e-9
    for i in range(n):
        ang[i] = (ang[i] - mid + math.pi) % (2.0 * math.pi) - math.pi
        if use[i] and abs(ang[i]) > half:
            half = abs(ang[i])
    a = np.zeros((3, 3))
    b = np.zeros(3)
    for i in range(n):
        if not use[i]:
            continue
        u = ang[i] / half
        row = (u * u, u, 1.0)
        t = math.log(res[i] * res[i] + floor)
        for j in range(3):
            b[j] += row[j] * t
            for k in range(3):
                a[j, k] += row[j] * row[k]
    coef = _solve3(a, b)
    v = np.empty(n)
    for i in range(n):
        u = ang[i] / half
        v[i] = math.exp(coef[0] * u * u + coef[1] * u + coef[2])
    med = np.median(v[use])
    for i in range(n):
        v[i] = min(max(v[i] / med, 1.0 / max_ratio), max_ratio)
    return v


@numba.njit(**_OPTS)
def rejection_clip(x: np.ndarray, y: np.ndarray, cx: float, cy: float, r: float,
                   sw: np.ndarray, inliers: np.ndarray, reject_k: float, floor: float
                   ) -> float:
    """``fit.rejection_clip`` compiled."""
    idx = np.flatnonzero(inliers)
    if idx.shape[0] == 0:
        return floor
    res = (_dist(x[idx], y[idx], cx, cy) - r) * sw[idx]
    return max(reject_k * _mad(res)[1], floor)


@numba.njit(**_OPTS)
def arc_span(x: np.ndarray, y: np.ndarray, cx: float, cy: float) -> float:
    """``fit.arc_span_deg`` compiled: 2 pi less the largest gap between the points' angles
    about (cx, cy), radians."""
    n = x.shape[0]
    a = np.empty(n)
    for i in range(n):
        a[i] = math.atan2(y[i] - cy, x[i] - cx)
    a.sort()
    widest = a[0] + 2.0 * math.pi - a[n - 1]
    for i in range(1, n):
        widest = max(widest, a[i] - a[i - 1])
    return 2.0 * math.pi - widest


@numba.njit(**_OPTS)
def view_cosines(section: np.ndarray, points3d: np.ndarray, cx: float, cy: float
                 ) -> np.ndarray:
    """``diameter.view_angles_deg``'s cosines compiled: of the angle between each point's
    radial direction about (cx, cy) and the line of sight back to the camera."""
    n = section.shape[0]
    out = np.empty(n)
    for i in range(n):
        sx, sy = section[i, 0], section[i, 1]
        rx, ry = sx - cx, sy - cy
        px, py, pz = points3d[i, 0], points3d[i, 1], points3d[i, 2]
        norms = math.sqrt(rx * rx + ry * ry) * math.sqrt(px * px + py * py + pz * pz)
        out[i] = min(max(-(rx * sx + ry * sy) / max(norms, 1e-300), -1.0), 1.0)
    return out


@numba.njit(**_OPTS)
def circle_rms(points: np.ndarray, cx: float, cy: float, r: float) -> float:
    """``fit.circle_rms`` compiled: RMS distance of the points from the circle."""
    acc = 0.0
    for i in range(points.shape[0]):
        dx, dy = points[i, 0] - cx, points[i, 1] - cy
        d = math.sqrt(dx * dx + dy * dy) - r
        acc += d * d
    return math.sqrt(acc / points.shape[0])


@numba.njit(**_OPTS)
def ring_consensus(section: np.ndarray, cx: float, cy: float, window: float,
                   scatter_sigmas: float) -> np.ndarray:
    """``consensus.ring_consensus`` compiled (the same steps, no temporary arrays' calls)."""
    n = section.shape[0]
    rho = np.empty(n)
    for i in range(n):
        rho[i] = math.hypot(section[i, 0] - cx, section[i, 1] - cy)
    s = np.sort(rho)
    best, i_best, end = -1, 0, 0
    for i in range(n):
        # The window [s_i, s_i + 2 w] holding the most radii (ends only move forward).
        end = max(end, i)
        top = s[i] + 2.0 * window
        while end < n and s[end] <= top:
            end += 1
        if end - i > best:
            best, i_best = end - i, i
    j = i_best
    top = s[j] + 2.0 * window
    k = j
    while k < n and s[k] <= top:
        k += 1
    radius = np.median(s[j:k])
    dev = np.abs(rho - radius)
    for _ in range(3):  # a cut sample understates its scatter: widen until it holds
        inside = dev[dev <= window]
        if inside.shape[0] == 0:
            break
        scatter = MAD_TO_SIGMA * np.median(inside)
        if not scatter_sigmas * scatter > window * 1.05:
            break
        window = scatter_sigmas * scatter
    return dev <= window


@numba.njit(**_OPTS)
def by_chain(inside: np.ndarray, labels: np.ndarray, min_share: float, min_on_circle: int
             ) -> np.ndarray:
    """``consensus.by_chain`` compiled, for labels in ``0 .. len(labels) * 4 + 1024``."""
    size = labels.max() + 1
    on = np.zeros(size)
    count = np.zeros(size)
    for i in range(labels.shape[0]):
        count[labels[i]] += 1.0
        if inside[i]:
            on[labels[i]] += 1.0
    out = np.empty(labels.shape[0], np.bool_)
    for i in range(labels.shape[0]):
        c = labels[i]
        out[i] = inside[i] and (on[c] / count[c] >= min_share or on[c] >= min_on_circle)
    return out
