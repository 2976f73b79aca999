"""Compiled kernels of the stripe extractor (numba): Steger's test on the pixels of a band only,
the refinement at float positions, and the local fits of the curvature correction.

They compute exactly what ``service.measure.stripe``'s reference numpy forms compute (the
tests hold them to it), but only where the stripe is: the separable derivative filters run on
the band's pixels and the few rows the filters reach beyond it, not over the band's bounding
box. No I/O; numba compiles them once and caches the machine code beside this file.
"""

from __future__ import annotations

import math

import numba
import numpy as np

_OPTS = dict(cache=True, nogil=True)
# The filter loops may be reordered and vectorised (sums of 13 products, rounding at 1e-7).
_FAST = dict(_OPTS, fastmath=True)


@numba.njit(**_FAST)
def band_hessian(roi: np.ndarray, band: np.ndarray, first: np.ndarray, last: np.ndarray,
                 g: np.ndarray, g1: np.ndarray, g2: np.ndarray) -> tuple[np.ndarray, ...]:
    """The Gaussian-smoothed image and its derivatives up to second order at every band pixel.

    Parameters
    ----------
    roi : ndarray of float32, shape (H, W)
        Image (background taken off).
    band : ndarray of bool, shape (H, W)
        Pixels to evaluate; those nearer the border than the kernels' radius are skipped.
    first, last : ndarray of int64, shape (H,)
        Each row's first and last column that may be in the band (``last < first`` for
        none; ``Band.row_spans``): only those are looked at.
    g, g1, g2 : ndarray of float32, shape (2r + 1,)
        Sampled Gaussian and its derivatives (``band.gaussian_kernels``), applied as
        OpenCV's ``sepFilter2D`` applies them (correlation).

    Returns
    -------
    iy, ix : ndarray of int64
        Band pixels evaluated, row by row.
    d : ndarray of float64, shape (N, 6)
        ``v, x, y, xx, yy, xy`` at each.

    Each row is filtered only over the span of columns its band pixels (and those of the r
    rows around it, for the vertical pass) occupy, with the column loop innermost so that it
    vectorises.
    """
    h, w = roi.shape
    r = (g.shape[0] - 1) // 2
    m = 2 * r + 1
    lo = np.full(h, w, np.int64)   # band span of each row: [lo, hi)
    hi = np.zeros(h, np.int64)
    count = 0
    for y in range(r, h - r):
        for x in range(max(r, first[y]), min(w - r, last[y] + 1)):
            if band[y, x]:
                count += 1
                lo[y] = min(lo[y], x)
                hi[y] = x + 1
    # The horizontal pass is needed wherever a band pixel within r rows needs it.
    nlo = np.full(h, w, np.int64)
    nhi = np.zeros(h, np.int64)
    for y in range(r, h - r):
        if hi[y] > lo[y]:
            for k in range(-r, r + 1):
                nlo[y + k] = min(nlo[y + k], lo[y])
                nhi[y + k] = max(nhi[y + k], hi[y])
    rows0 = np.empty((h, w), np.float32)  # written only where they are read
    rows1 = np.empty((h, w), np.float32)
    rows2 = np.empty((h, w), np.float32)
    for y in range(h):
        for x in range(nlo[y], nhi[y]):
            rows0[y, x] = 0.0
            rows1[y, x] = 0.0
            rows2[y, x] = 0.0
        for k in range(m):
            gk, g1k, g2k = g[k], g1[k], g2[k]
            for x in range(nlo[y], nhi[y]):
                p = roi[y, x + k - r]
                rows0[y, x] += gk * p
                rows1[y, x] += g1k * p
                rows2[y, x] += g2k * p
    iy = np.empty(count, np.int64)
    ix = np.empty(count, np.int64)
    d = np.empty((count, 6), np.float64)
    acc = np.zeros((6, w), np.float32)
    n = 0
    for y in range(r, h - r):
        a, b = lo[y], hi[y]
        if b <= a:
            continue
        acc[:, a:b] = 0.0
        for k in range(m):
            gk, g1k, g2k = g[k], g1[k], g2[k]
            yy = y + k - r
            for x in range(a, b):
                c0 = rows0[yy, x]
                c1 = rows1[yy, x]
                acc[0, x] += gk * c0
                acc[1, x] += gk * c1
                acc[2, x] += g1k * c0
                acc[3, x] += gk * rows2[yy, x]
                acc[4, x] += g2k * c0
                acc[5, x] += g1k * c1
        for x in range(a, b):
            if band[y, x]:
                iy[n] = y
                ix[n] = x
                for j in range(6):
                    d[n, j] = acc[j, x]
                n += 1
    return iy, ix, d


@numba.njit(**_OPTS)
def steger_test(d: np.ndarray, min_curvature: float, search: float
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Steger's first step at pixels with derivatives ``d`` (rows ``v, x, y, xx, yy, xy``):
    the line normal from the Hessian's eigenvector of the most negative eigenvalue, the
    offset ``t`` along it, and the test (a ridge, stronger across than along, curvature above
    ``min_curvature``, the centre within ``search`` px of the pixel).

    Returns
    -------
    index, nx, ny, t : ndarray
        Rows of ``d`` that pass, with their normal and offset.
    """
    n = d.shape[0]
    index = np.empty(n, np.int64)
    nxs = np.empty(n)
    nys = np.empty(n)
    ts = np.empty(n)
    m = 0
    for i in range(n):
        gx, gy, hxx, hyy, hxy = d[i, 1], d[i, 2], d[i, 3], d[i, 4], d[i, 5]
        half_tr = 0.5 * (hxx + hyy)
        hd = 0.5 * (hxx - hyy)
        root = math.sqrt(hd * hd + hxy * hxy)  # moderate values: no need of hypot's care
        lam_lo = half_tr - root
        lam_hi = half_tr + root
        if not (lam_lo < 0.0 and abs(lam_lo) > abs(lam_hi) and -lam_lo > min_curvature):
            continue
        # The eigenvector of the low eigenvalue, (-sin theta, cos theta) with theta =
        # atan2(2 hxy, hxx - hyy) / 2 (so ny >= 0), from half-angle formulas: no trigonometry.
        c2 = 0.5 * (hxx - hyy) / root if root > 0.0 else 1.0   # cos 2 theta
        s2 = hxy / root if root > 0.0 else 0.0                  # sin 2 theta
        ny = math.sqrt(max(0.0, 0.5 * (1.0 + c2)))
        nx = -math.copysign(math.sqrt(max(0.0, 0.5 * (1.0 - c2))), s2)
        if ny == 0.0:
            nx = -1.0
        t = -(nx * gx + ny * gy) / lam_lo
        if abs(t * nx) <= search and abs(t * ny) <= search:
            index[m] = i
            nxs[m] = nx
            nys[m] = ny
            ts[m] = t
            m += 1
    return index[:m], nxs[:m], nys[:m], ts[:m]


@numba.njit(**_FAST)
def derivatives_at(image: np.ndarray, x: np.ndarray, y: np.ndarray, sigma: float
                   ) -> np.ndarray:
    """``stripe.derivatives_at`` compiled: the continuous-Gaussian derivatives at float
    positions, as an (N, 6) array ``v, x, y, xx, xy, yy``.

    Each kernel's Gaussian at offset ``f`` is ``exp(-j^2 / 2s^2)`` times ``q^j``, ``q =
    exp(f / s^2)``, times ``exp(-f^2 / 2s^2)``: three exponentials a point and axis, not
    thirteen (half the kernel's time went to them)."""
    h, w = image.shape
    r = max(1, math.ceil(4.0 * sigma))
    m = 2 * r + 1
    out = np.empty((x.shape[0], 6), np.float64)
    norm = 1.0 / (math.sqrt(2.0 * math.pi) * sigma)
    inv_s2 = 1.0 / (sigma * sigma)
    base = np.empty(m)
    for j in range(m):
        base[j] = math.exp(-0.5 * (j - r) ** 2 * inv_s2) * norm
    kx = np.empty((3, m))
    ky = np.empty((3, m))
    rows = np.empty((3, m))
    for i in range(x.shape[0]):
        cx = min(max(int(np.rint(x[i])), r), w - 1 - r)
        cy = min(max(int(np.rint(y[i])), r), h - 1 - r)
        fx, fy = x[i] - cx, y[i] - cy
        qx, qy = math.exp(fx * inv_s2), math.exp(fy * inv_s2)
        px = math.exp(-0.5 * fx * fx * inv_s2) * qx ** -r
        py = math.exp(-0.5 * fy * fy * inv_s2) * qy ** -r
        for j in range(m):
            u = ((j - r) - fx) / sigma
            gv = base[j] * px
            px *= qx
            kx[0, j] = gv
            kx[1, j] = u / sigma * gv
            kx[2, j] = (u * u - 1.0) * inv_s2 * gv
            u = ((j - r) - fy) / sigma
            gv = base[j] * py
            py *= qy
            ky[0, j] = gv
            ky[1, j] = u / sigma * gv
            ky[2, j] = (u * u - 1.0) * inv_s2 * gv
        for a in range(m):
            row = image[cy - r + a, cx - r:cx + r + 1]
            s0 = 0.0
            s1 = 0.0
            s2 = 0.0
            for b in range(m):
                p = float(row[b])
                s0 += kx[0, b] * p
                s1 += kx[1, b] * p
                s2 += kx[2, b] * p
            rows[0, a] = s0
            rows[1, a] = s1
            rows[2, a] = s2
        v = dx = dy = dxx = dxy = dyy = 0.0
        for a in range(m):
            v += ky[0, a] * rows[0, a]
            dx += ky[0, a] * rows[1, a]
            dy += ky[1, a] * rows[0, a]
            dxx += ky[0, a] * rows[2, a]
            dyy += ky[2, a] * rows[0, a]
            dxy += ky[1, a] * rows[1, a]
        out[i, 0] = v
        out[i, 1] = dx
        out[i, 2] = dy
        out[i, 3] = dxx
        out[i, 4] = dxy
        out[i, 5] = dyy
    return out


@numba.njit(**_OPTS)
def local_parabolas(xy: np.ndarray, normal: np.ndarray, idx: np.ndarray, window_px: float
                    ) -> np.ndarray:
    """For each centre, ``c`` of ``v = a + b u + c u^2`` fitted with Gaussian weights (half
    width ``window_px`` along the stripe) to its neighbours ``idx`` in the frame of its own
    tangent ``u`` and normal ``v`` (``stripe.correct_curvature_bias``)."""
    n, k = idx.shape
    out = np.empty(n)
    for i in range(n):
        tx, ty = -normal[i, 1], normal[i, 0]
        # The normal equations' sums, w u^p (p = 0..4) and w u^p v (p = 0..2), as scalars.
        s0 = s1 = s2 = s3 = s4 = r0 = r1 = r2 = 0.0
        for j in range(k):
            q = idx[i, j]
            rx = xy[q, 0] - xy[i, 0]
            ry = xy[q, 1] - xy[i, 1]
            u = rx * tx + ry * ty
            v = rx * normal[i, 0] + ry * normal[i, 1]
            if abs(v) >= 2.0:
                continue  # a parallel stray line
            wgt = math.exp(-0.5 * (u / window_px) ** 2)
            wu = wgt * u
            wu2 = wu * u
            s0 += wgt
            s1 += wu
            s2 += wu2
            s3 += wu2 * u
            s4 += wu2 * u * u
            r0 += wgt * v
            r1 += wu * v
            r2 += wu2 * v
        s0 += 1e-9
        s4 += 1e-9
        det = _det3(s0, s1, s2, s1, s2 + 1e-9, s3, s2, s3, s4)
        out[i] = 0.0 if det == 0.0 else \
            _det3(s0, s1, r0, s1, s2 + 1e-9, r1, s2, s3, r2) / det
    return out


@numba.njit(**_OPTS)
def _det3(a00: float, a01: float, a02: float, a10: float, a11: float, a12: float,
          a20: float, a21: float, a22: float) -> float:
    return (a00 * (a11 * a22 - a12 * a21) - a01 * (a10 * a22 - a12 * a20)
            + a02 * (a10 * a21 - a11 * a20))


@numba.njit(**_OPTS)
def end_extensions(xy: np.ndarray, length_px: int, span: int) -> np.ndarray:
    """``band.extend_ends`` compiled: the points beyond each end of the line that ``xy``
    forms, one a pixel for ``length_px`` along its direction there; the ends are the extremes
    along the principal direction (the 2x2 covariance's major eigenvector), the direction the
    mean of the ``span`` points nearest an end less that of the ``span`` next ones."""
    n = xy.shape[0]
    out = np.empty((2 * length_px, 2))
    if n < 2 * span or length_px <= 0:
        return out[:0]
    mx, my = 0.0, 0.0
    for i in range(n):
        mx += xy[i, 0]
        my += xy[i, 1]
    mx /= n
    my /= n
    sxx, syy, sxy = 0.0, 0.0, 0.0
    for i in range(n):
        dx, dy = xy[i, 0] - mx, xy[i, 1] - my
        sxx += dx * dx
        syy += dy * dy
        sxy += dx * dy
    # The major axis of [[sxx, sxy], [sxy, syy]] at angle atan2(2 sxy, sxx - syy) / 2.
    theta = 0.5 * math.atan2(2.0 * sxy, sxx - syy)
    ux, uy = math.cos(theta), math.sin(theta)
    proj = np.empty(n)
    for i in range(n):
        proj[i] = (xy[i, 0] - mx) * ux + (xy[i, 1] - my) * uy
    order = np.argsort(proj)
    m = 0
    for side in range(2):
        ax, ay, bx, by = 0.0, 0.0, 0.0, 0.0
        for j in range(span):
            e = order[j] if side == 0 else order[n - 1 - j]
            q = order[span + j] if side == 0 else order[n - 1 - span - j]
            ax += xy[e, 0]
            ay += xy[e, 1]
            bx += xy[q, 0]
            by += xy[q, 1]
        dx, dy = (ax - bx) / span, (ay - by) / span
        norm = math.hypot(dx, dy)
        if norm == 0.0:
            continue
        tip = order[0] if side == 0 else order[n - 1]
        for k in range(1, length_px + 1):
            out[m, 0] = xy[tip, 0] + k * dx / norm
            out[m, 1] = xy[tip, 1] + k * dy / norm
            m += 1
    return out[:m]


@numba.njit(**_OPTS)
def disc_mask(h: int, w: int, ys: np.ndarray, xs: np.ndarray, radius: int
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A (h, w) mask of the pixels within ``radius`` px of any of the points (``ys``, ``xs``,
    integer pixels, may lie outside), with each row's first and last pixel in it (``last <
    first`` in a row with none)."""
    mask = np.zeros((h, w), np.bool_)
    first = np.full(h, w, np.int64)
    last = np.full(h, -1, np.int64)
    r2 = radius * radius
    for i in range(ys.shape[0]):
        for dy in range(-radius, radius + 1):
            y = ys[i] + dy
            if y < 0 or y >= h:
                continue
            span = int(math.sqrt(r2 - dy * dy))
            a, b = max(0, xs[i] - span), min(w, xs[i] + span + 1)
            if b > a:
                first[y] = min(first[y], a)
                last[y] = max(last[y], b - 1)
            for x in range(a, b):
                mask[y, x] = True
    return mask, first, last


@numba.njit(**_OPTS)
def background_and_noise(image: np.ndarray, k: int, spacing: int) -> tuple[float, float]:
    """The median of the means of ``k``-square blocks (one block in ``spacing`` each way), and
    the pixels' noise: from the differences of horizontally paired pixels within each block
    (half their mean square is the block's variance), the median over the darker three
    quarters of the blocks, made unbiased for the median of a chi-square (Wilson-Hilferty).
    Differences of neighbours leave out whatever varies slowly (a light gradient, shading,
    a wide bright part), which block means would count as noise."""
    hb, wb = image.shape[0] // k, image.shape[1] // k
    ny, nx = (hb + spacing - 1) // spacing, (wb + spacing - 1) // spacing
    sums = np.zeros(ny * nx)
    squares = np.zeros(ny * nx)
    pairs = k * (k // 2)
    # Row by row across the blocks, not block by block: the rows are read in order, which
    # the prefetcher follows (a new frame is not in the cache; twice as fast, same sums).
    m = 0
    for by in range(0, hb, spacing):
        for y in range(by * k, by * k + k):
            j = m
            for bx in range(0, wb, spacing):
                acc = sums[j]
                sq = squares[j]
                for x in range(bx * k, bx * k + k):
                    acc += image[y, x]
                for x in range(bx * k, bx * k + k - 1, 2):
                    d = float(image[y, x + 1]) - float(image[y, x])
                    sq += d * d
                sums[j] = acc
                squares[j] = sq
                j += 1
        m += nx
    means = sums[:m] / (k * k)
    variances = squares[:m] / (2.0 * pairs) if pairs > 0 else np.zeros(m)
    background = np.median(means)
    dark = variances[means <= np.percentile(means, 75.0)]
    median_of_chi2 = (1.0 - 2.0 / (9.0 * max(pairs, 1))) ** 3
    return background, math.sqrt(np.median(dark) / median_of_chi2)


@numba.njit(**_OPTS)
def block_means(image: np.ndarray, k: int, spacing: int) -> np.ndarray:
    """Means of the ``k``-square blocks of ``image``, one block in ``spacing`` each way."""
    hb, wb = image.shape[0] // k, image.shape[1] // k
    ny, nx = (hb + spacing - 1) // spacing, (wb + spacing - 1) // spacing
    out = np.empty(ny * nx)
    m = 0
    for by in range(0, hb, spacing):
        for bx in range(0, wb, spacing):
            acc = 0.0
            for y in range(by * k, by * k + k):
                for x in range(bx * k, bx * k + k):
                    acc += image[y, x]
            out[m] = acc / (k * k)
            m += 1
    return out[:m]


@numba.njit(**_OPTS)
def _sweep_order(xy: np.ndarray) -> tuple[np.ndarray, int]:
    """Points sorted along the coordinate (0: x, 1: y) they spread most in, and which."""
    axis = 1 if np.ptp(xy[:, 1]) > np.ptp(xy[:, 0]) else 0
    return np.argsort(xy[:, axis]), axis


@numba.njit(**_OPTS)
def nearest_neighbours(xy: np.ndarray, k: int) -> np.ndarray:
    """Indices of each point's ``k`` nearest points (itself first), nearest first: what
    ``cKDTree(xy).query(xy, k)`` gives, by a sweep along the points' longer extent (a
    stripe's centres lie along a curve, so few candidates are looked at)."""
    n = xy.shape[0]
    order, axis = _sweep_order(xy)
    rank = np.empty(n, np.int64)
    for i in range(n):
        rank[order[i]] = i
    out = np.empty((n, k), np.int64)
    best_d = np.empty(k)
    best_i = np.empty(k, np.int64)
    for i in range(n):
        filled = 0
        lo, hi = rank[i] - 1, rank[i]  # the next candidates below and above
        while lo >= 0 or hi < n:
            # The nearer along the sweep first: distances then come nearly in order, and
            # each insertion moves few of the best.
            a_lo = xy[i, axis] - xy[order[lo], axis] if lo >= 0 else np.inf
            a_hi = xy[order[hi], axis] - xy[i, axis] if hi < n else np.inf
            if a_lo <= a_hi:
                q, along = order[lo], a_lo
                lo -= 1
            else:
                q, along = order[hi], a_hi
                hi += 1
            if filled == k and along * along > best_d[k - 1]:
                break  # every candidate left is farther along than the k-th is away
            dx, dy = xy[q, 0] - xy[i, 0], xy[q, 1] - xy[i, 1]
            d2 = dx * dx + dy * dy
            if filled < k or d2 < best_d[k - 1]:
                pos = filled if filled < k else k - 1
                while pos > 0 and best_d[pos - 1] > d2:
                    if pos < k:
                        best_d[pos] = best_d[pos - 1]
                        best_i[pos] = best_i[pos - 1]
                    pos -= 1
                best_d[pos] = d2
                best_i[pos] = q
                if filled < k:
                    filled += 1
        out[i, :] = best_i
    return out


@numba.njit(**_OPTS)
def _root(parent: np.ndarray, i: int) -> int:
    while parent[i] != i:
        parent[i] = parent[parent[i]]
        i = parent[i]
    return i


@numba.njit(**_OPTS)
def chain_labels(xy: np.ndarray, gap: float) -> np.ndarray:
    """For each point, its chain's label (the index of one of its points): points linked when
    no farther apart than ``gap`` (px), chains the connected sets (union-find over a sweep)."""
    n = xy.shape[0]
    order, axis = _sweep_order(xy)
    parent = np.arange(n)
    g2 = gap * gap
    for a in range(n):
        i = order[a]
        for b in range(a + 1, n):
            q = order[b]
            along = xy[q, axis] - xy[i, axis]
            if along > gap:
                break
            dx, dy = xy[q, 0] - xy[i, 0], xy[q, 1] - xy[i, 1]
            if dx * dx + dy * dy <= g2:
                ri, rq = _root(parent, i), _root(parent, q)
                if ri != rq:
                    parent[ri] = rq
    out = np.empty(n, np.int64)
    for i in range(n):
        out[i] = _root(parent, i)
    return out


@numba.njit(**_OPTS)
def chain_sizes(labels: np.ndarray) -> np.ndarray:
    """For each point, the number of points with its label (``chain_labels``)."""
    sizes = np.zeros(labels.shape[0], np.int64)
    for i in range(labels.shape[0]):
        sizes[labels[i]] += 1
    out = np.empty(labels.shape[0], np.int64)
    for i in range(labels.shape[0]):
        out[i] = sizes[labels[i]]
    return out


@numba.njit(**_OPTS)
def _linear_taps(n_out: int, n_in: int, n_covered: int) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV's INTER_LINEAR source pixel and weight of the next one for each of ``n_out``
    destination pixels, ``n_in`` source pixels spanning the first ``n_covered`` of them
    (pixel centres aligned, edges clamped)."""
    scale = n_in / n_covered
    i0 = np.empty(n_out, np.int64)
    frac = np.empty(n_out)
    for i in range(n_out):
        f = (i + 0.5) * scale - 0.5
        j = math.floor(f)
        a = f - j
        if j < 0:
            j, a = 0, 0.0
        if j >= n_in - 1:
            j, a = n_in - 1, 0.0
        i0[i] = j
        frac[i] = a
    return i0, frac


@numba.njit(**_FAST)
def subtract_upsampled(image: np.ndarray, small: np.ndarray, level: float, step: int,
                       cover_h: int, cover_w: int, first: np.ndarray, last: np.ndarray,
                       pad: int) -> np.ndarray:
    """``image - up(small) - m + level`` (float32), with ``up`` the bilinear resize of
    ``small`` to ``image``'s first ``cover_h`` rows and ``cover_w`` columns as
    ``cv2.resize(..., INTER_LINEAR)`` makes it (held at its edge beyond them) and ``m`` the
    median of ``image - up(small)`` over every ``step``-th pixel each way; without the
    full-size background (each row of it interpolated once, used at once).

    With ``first`` and ``last`` (each row's first and last column needed, ``last < first``
    for none; empty for all of the image) only the pixels within ``pad`` px (a box) of
    those spans are computed, in place: the others keep the image's values (a curved
    stripe's band fills a fifth of its box, and writing the rest costs as much as the
    band)."""
    h, w = image.shape
    sh, sw = small.shape
    lo = np.zeros(h, np.int64)  # columns computed in each row: [lo, hi)
    hi = np.full(h, w, np.int64)
    if first.size:
        hi[:] = 0
        lo[:] = w
        for y in range(h):
            if last[y] >= first[y]:
                for k in range(max(0, y - pad), min(h, y + pad + 1)):
                    lo[k] = min(lo[k], max(0, first[y] - pad))
                    hi[k] = max(hi[k], min(w, last[y] + pad + 1))
    ry, fy = _linear_taps(h, sh, cover_h)
    rx, fx = _linear_taps(w, sw, cover_w)
    rx1 = np.minimum(rx + 1, sw - 1)
    samples = np.empty(((h + step - 1) // step) * ((w + step - 1) // step))
    m = 0
    for y in range(0, h, step):
        y0, y1, b = ry[y], min(ry[y] + 1, sh - 1), fy[y]
        for x in range(0, w, step):
            a = fx[x]
            top = (1.0 - a) * small[y0, rx[x]] + a * small[y0, rx1[x]]
            bottom = (1.0 - a) * small[y1, rx[x]] + a * small[y1, rx1[x]]
            samples[m] = image[y, x] - ((1.0 - b) * top + b * bottom)
            m += 1
    shift = level - np.median(samples[:m])
    # Each pixel depends on itself alone: in place is safe.
    out = image if first.size else np.empty((h, w), np.float32)
    row = np.empty(sw)
    for y in range(h):
        a0, a1 = lo[y], hi[y]
        if a1 <= a0:
            continue
        y0, y1, b = ry[y], min(ry[y] + 1, sh - 1), fy[y]
        for j in range(rx[a0], min(rx1[a1 - 1] + 1, sw)):
            row[j] = (1.0 - b) * small[y0, j] + b * small[y1, j]
        for x in range(a0, a1):
            a = fx[x]
            out[y, x] = image[y, x] + shift - ((1.0 - a) * row[rx[x]] + a * row[rx1[x]])
    return out


@numba.njit(**_OPTS)
def in_patch(xy: np.ndarray, labels: np.ndarray, max_density: float) -> np.ndarray:
    """For each point, whether its chain (``chain_labels``) is a patch: more than
    ``max_density`` points per pixel of the diagonal of its box (at least 1 px)."""
    n = labels.shape[0]
    lo = np.full((n, 2), np.inf)
    hi = np.full((n, 2), -np.inf)
    counts = np.zeros(n, np.int64)
    for i in range(n):
        c = labels[i]
        counts[c] += 1
        for j in range(2):
            lo[c, j] = min(lo[c, j], xy[i, j])
            hi[c, j] = max(hi[c, j], xy[i, j])
    out = np.empty(n, np.bool_)
    for i in range(n):
        c = labels[i]
        extent = math.hypot(hi[c, 0] - lo[c, 0], hi[c, 1] - lo[c, 1])
        out[i] = counts[c] > max_density * max(extent, 1.0)
    return out


@numba.njit(**_OPTS)
def side_balance(roi: np.ndarray, x: np.ndarray, y: np.ndarray, nx: np.ndarray,
                 ny: np.ndarray, peak: np.ndarray) -> np.ndarray:
    """How lopsided each centre's profile is: the mean over 2, 3, 4 and 5 px along the normal
    of the grey level on one side less that on the other (bilinear, on ``roi`` with its
    background taken off), over the profile's height. About 0.02 for a stripe alone; a second
    line a few pixels beside it (a reflection) makes it 0.05-0.2."""
    h, w = roi.shape
    out = np.empty(x.shape[0])
    for i in range(x.shape[0]):
        acc = 0.0
        for step in range(2, 6):
            for sign in (1.0, -1.0):
                px = x[i] + sign * step * nx[i]
                py = y[i] + sign * step * ny[i]
                x0 = min(max(math.floor(px), 0), w - 2)
                y0 = min(max(math.floor(py), 0), h - 2)
                fx = min(max(px - x0, 0.0), 1.0)
                fy = min(max(py - y0, 0.0), 1.0)
                v = ((1 - fy) * ((1 - fx) * roi[y0, x0] + fx * roi[y0, x0 + 1])
                     + fy * ((1 - fx) * roi[y0 + 1, x0] + fx * roi[y0 + 1, x0 + 1]))
                acc += sign * v
        out[i] = acc / 4.0 / max(peak[i], 1e-6)
    return out


@numba.njit(**_OPTS)
def refine_centres(roi: np.ndarray, iy: np.ndarray, ix: np.ndarray, nx: np.ndarray,
                   ny: np.ndarray, t: np.ndarray, sigma: float, background: float,
                   half_pixel: float) -> tuple[np.ndarray, ...]:
    """One Newton step along each normal with the derivatives at the first estimate, and the
    centres that stay within ``half_pixel`` of their pixel on a ridge.

    Returns
    -------
    x, y, nx, ny, strength, width, peak : ndarray
        Centres (roi px), unit normals, curvature across the line, the line's own Gaussian
        sigma (px) and the smoothed profile's height above ``background``.
    """
    n = iy.shape[0]
    at = derivatives_at(roi, ix + t * nx, iy + t * ny, sigma)
    out = np.empty((7, n))
    m = 0
    for i in range(n):
        a, b = nx[i], ny[i]
        g_n = a * at[i, 1] + b * at[i, 2]
        h_nn = a * a * at[i, 3] + 2.0 * a * b * at[i, 4] + b * b * at[i, 5]
        if not h_nn < 0.0:
            continue
        ti = t[i] - g_n / h_nn
        if abs(ti * a) > half_pixel or abs(ti * b) > half_pixel:
            continue
        peak = at[i, 0] - background
        # Smoothed profile of a Gaussian line of sigma w: V'' = -V / (w^2 + s^2) there.
        w2 = peak / -h_nn - sigma * sigma
        out[0, m] = ix[i] + ti * a
        out[1, m] = iy[i] + ti * b
        out[2, m] = a
        out[3, m] = b
        out[4, m] = -h_nn
        out[5, m] = math.sqrt(w2) if w2 > 0.0 else 0.0
        out[6, m] = peak
        m += 1
    return (out[0, :m], out[1, :m], out[2, :m], out[3, :m], out[4, :m], out[5, :m],
            out[6, :m])


@numba.njit(**_OPTS)
def not_weak(strength: np.ndarray, width: np.ndarray, min_relative: float, lo: float,
             hi: float) -> np.ndarray:
    """Centres whose curvature reaches ``min_relative`` of the 90th percentile and whose
    width lies within [lo, hi] times the median width of the strongest tenth
    (``stripe.reject_weak``): the laser's stripe is the sharpest line in the frame, though not
    always the longest (a lit machine edge crossing the frame gives five times its centres,
    nine pixels wide, and their median width had the stripe's own centres dropped)."""
    p90 = np.percentile(strength, 90.0)
    keep = strength >= min_relative * p90
    if keep.any():
        med = np.median(width[strength >= p90])
        if med > 0.0:
            keep &= (width >= lo * med) & (width <= hi * med)
    return keep
