"""The compiled kernels against the reference forms they replace: OpenCV's separable filters,
the numpy continuous-Gaussian derivatives, scipy's k-d tree and connected components, scipy's
least_squares; and tracking against a full search."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from scipy.optimize import least_squares
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from service.measure import circle_kernels as ck
from service.measure import consensus, sheet_kernels
from service.measure import steger_kernels as sk
from service.measure.band import gaussian_kernels, tube_band
from service.measure.stripe import StripeParams, extract_stripe


def _speckled(seed: int, shape: tuple[int, int] = (60, 80)) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return cv2.GaussianBlur(rng.uniform(0, 200, shape).astype(np.float32), (0, 0), 1.2)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_band_hessian_equals_opencv_filters(seed: int) -> None:
    roi = _speckled(seed)
    band = np.random.default_rng(seed + 10).random(roi.shape) < 0.3
    g, g1, g2 = gaussian_kernels(1.5)
    h, w = roi.shape
    iy, ix, d = sk.band_hessian(roi, band, np.zeros(h, np.int64), np.full(h, w - 1), g, g1, g2)
    r = (len(g) - 1) // 2
    inner = band.copy()
    inner[:r], inner[-r:], inner[:, :r], inner[:, -r:] = False, False, False, False
    assert np.array_equal(np.column_stack([iy, ix]), np.argwhere(inner))
    for col, (kx, ky) in enumerate([(g, g), (g1, g), (g, g1), (g2, g), (g, g2), (g1, g1)]):
        ref = cv2.sepFilter2D(roi, cv2.CV_32F, kx, ky, borderType=cv2.BORDER_REPLICATE)
        np.testing.assert_allclose(d[:, col], ref[iy, ix], rtol=1e-4, atol=1e-3)


def _derivatives_reference(image: np.ndarray, x: np.ndarray, y: np.ndarray, sigma: float
                           ) -> np.ndarray:
    """The continuous Gaussian's derivatives at float positions, summed in numpy."""
    r = max(1, math.ceil(4.0 * sigma))
    out = []
    for px, py in zip(x, y, strict=True):
        cx, cy = int(np.rint(px)), int(np.rint(py))
        k = np.arange(-r, r + 1)
        ux, uy = (k - (px - cx)) / sigma, (k - (py - cy)) / sigma
        gx, gy = (np.exp(-0.5 * u * u) / (math.sqrt(2 * math.pi) * sigma) for u in (ux, uy))
        kx = [gx, ux / sigma * gx, (ux * ux - 1) / sigma**2 * gx]
        ky = [gy, uy / sigma * gy, (uy * uy - 1) / sigma**2 * gy]
        patch = image[cy - r:cy + r + 1, cx - r:cx + r + 1].astype(np.float64)
        val = [ky[a] @ patch @ kx[b] for a, b in [(0, 0), (0, 1), (1, 0), (0, 2), (1, 1),
                                                   (2, 0)]]
        out.append(val)
    return np.array(out)


def test_derivatives_at_float_positions_equal_the_numpy_sum() -> None:
    image = _speckled(4)
    rng = np.random.default_rng(5)
    x, y = rng.uniform(10, 70, 50), rng.uniform(10, 50, 50)
    np.testing.assert_allclose(sk.derivatives_at(image, x, y, 1.5),
                               _derivatives_reference(image, x, y, 1.5), rtol=1e-9, atol=1e-9)


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 10_000), st.integers(5, 300), st.integers(2, 25))
def test_nearest_neighbours_are_the_k_d_tree_s(seed: int, n: int, k: int) -> None:
    rng = np.random.default_rng(seed)
    t = np.sort(rng.uniform(0, 6, n))
    xy = np.column_stack([80 * np.cos(t), 300 * t]) + rng.normal(0, 0.5, (n, 2))
    k = min(k, n)
    got = sk.nearest_neighbours(xy, k)
    dist, _ = cKDTree(xy).query(xy, k=k)
    got_d = np.hypot(*(xy[got] - xy[:, None, :]).transpose(2, 0, 1))
    np.testing.assert_allclose(got_d, dist.reshape(n, k), atol=1e-12)  # ties may swap


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 10_000), st.integers(2, 300))
def test_chain_sizes_are_the_connected_components(seed: int, n: int) -> None:
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0, 40, (n, 2))
    pairs = cKDTree(xy).query_pairs(2.0, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, labels = connected_components(graph, directed=False)
    chains = sk.chain_labels(xy, 2.0)
    assert np.array_equal(sk.chain_sizes(chains), np.bincount(labels)[labels])
    # The same partition: each chain is one component and each component one chain.
    assert len(set(zip(chains, labels, strict=True))) == len(set(labels)) == len(set(chains))


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 10_000), st.floats(0.2, 3.0), st.booleans())
@example(400, 0.510050210313215, False)  # 0.43 nm apart: failed the nanometre bound once
def test_circle_solve_reaches_scipy_s_minimum(seed: int, arc: float, prior: bool) -> None:
    rng = np.random.default_rng(seed)
    a = rng.uniform(0.0, arc, 200)
    x, y = 3 + 20 * np.cos(a) + rng.normal(0, 0.01, 200), -2 + 20 * np.sin(a) \
        + rng.normal(0, 0.01, 200)
    w = rng.uniform(0.2, 1.0, 200)
    c0, inv_s2 = (np.array([3.0, -2.0]), 1e4) if prior else (np.zeros(2), 0.0)

    def res(q: np.ndarray) -> np.ndarray:
        d = np.sqrt(w) * (np.hypot(x - q[0], y - q[1]) - q[2])
        return np.concatenate([d, math.sqrt(inv_s2) * (q[:2] - c0)])

    start = np.array([3.05, -2.05, 19.9])
    sol = least_squares(res, start, method="lm", xtol=1e-14, ftol=1e-14)
    ref = sol.x
    cx, cy, r, ok = ck.solve_circle(x, y, w, *start, c0[0], c0[1], inv_s2)
    assert ok
    cost = float(np.sum(res(np.array([cx, cy, r])) ** 2))
    assert cost <= float(np.sum(res(ref) ** 2)) * (1 + 1e-9)
    if arc > 0.5:
        # The same parameters, to 1e-4 of their standard errors: on a short arc the minimum
        # is a long flat valley where both solvers stop a few tenths of a nanometre apart
        # (arc 0.51 rad: up to 1e-5 of the errors, 0.8 nm, in 2,600 cases).
        sigma = np.sqrt(np.diag(np.linalg.inv(sol.jac.T @ sol.jac))
                        * np.sum(sol.fun ** 2) / (len(sol.fun) - 3))
        assert np.all(np.abs(np.array([cx, cy, r]) - ref) <= 1e-4 * sigma)
    if arc > 1.0:  # a well-posed circle: to well under a nanometre
        np.testing.assert_allclose([cx, cy, r], ref, atol=1e-7)


def _extend_ends_numpy(pts: np.ndarray, length_px: int, span: int = 15) -> np.ndarray:
    """The form ``end_extensions`` replaced: the principal direction by SVD."""
    centred = pts - pts.mean(axis=0)
    _, _, vt = np.linalg.svd(centred, full_matrices=False)
    order = np.argsort(centred @ vt[0])
    steps = np.arange(1.0, length_px + 1.0)
    extra = []
    for tip, end, inner in ((order[0], order[:span], order[span:2 * span]),
                            (order[-1], order[-span:], order[-2 * span:-span])):
        direction = pts[end].mean(axis=0) - pts[inner].mean(axis=0)
        extra.append(pts[tip] + steps[:, None] * (direction / np.hypot(*direction)))
    return np.concatenate(extra)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 10_000), st.floats(0.2, 2.5), st.integers(30, 400))
def test_end_extensions_are_those_of_the_svd(seed: int, arc: float, n: int) -> None:
    rng = np.random.default_rng(seed)
    a = np.sort(rng.uniform(0.0, arc, n)) + rng.uniform(0, 6.3)
    xy = np.column_stack([500 + 200 * np.cos(a), 400 + 150 * np.sin(a)]) \
        + rng.normal(0, 0.3, (n, 2))
    got = sk.end_extensions(xy, 15, 15)
    want = _extend_ends_numpy(xy, 15)
    # The same two runs of points (the ends may come in either order).
    key = lambda p: tuple(np.round(p[0], 6))  # noqa: E731
    assert sorted([got[:15], got[15:]], key=key)[0] == pytest.approx(
        sorted([want[:15], want[15:]], key=key)[0], abs=1e-9)
    assert sorted([got[:15], got[15:]], key=key)[1] == pytest.approx(
        sorted([want[:15], want[15:]], key=key)[1], abs=1e-9)


def test_tracked_frames_give_the_points_of_a_full_search(renderer) -> None:
    images = [renderer.render(33.0, i) for i in range(8)]
    params = StripeParams()
    near = extract_stripe(images[0], params).xy
    for image in images[1:]:
        full = extract_stripe(image, params)
        tracked = extract_stripe(image, params, near)
        # The same stripe, end to end; the centres differ only by the background estimated
        # over another box (a few thousandths of a pixel).
        assert abs(len(tracked) - len(full)) <= 0.03 * len(full)
        dist, _ = cKDTree(full.xy).query(tracked.xy)
        assert np.median(dist) < 0.005 and np.percentile(dist, 95) < 0.02
        # The ends are not lost from frame to frame (the stripe runs top to bottom here).
        assert np.ptp(tracked.xy[:, 1]) == pytest.approx(np.ptp(full.xy[:, 1]), rel=0.02)
        near = tracked.xy


def test_a_stripe_that_moved_is_found_by_a_full_search(renderer) -> None:
    image = renderer.render(33.0, 0)
    params = StripeParams()
    full = extract_stripe(image, params)
    far = full.xy + np.array([60.0, 0.0])  # where the stripe was: 60 px to the right
    moved = extract_stripe(image, params, far)
    assert len(moved) == len(full)
    assert tube_band(far, image.shape, params.track_px) is not None


@pytest.mark.parametrize("shape", [(417, 397), (40, 57), (6, 9), (128, 64)])
def test_background_subtracted_in_one_pass_equals_opencv_s_resize(shape: tuple[int, int]
                                                                 ) -> None:
    """``subtract_upsampled`` is the image less ``cv2.resize(small, INTER_LINEAR)`` over the
    even part of the image that ``small`` halves (its last row and column held beyond) less
    the median of the difference over every sixth pixel, plus the level."""
    rng = np.random.default_rng(shape[0])
    image = rng.uniform(0, 255, shape).astype(np.float32)
    h2, w2 = shape[0] // 2, shape[1] // 2
    small = cv2.GaussianBlur(rng.uniform(0, 60, (h2, w2)).astype(np.float32), (0, 0), 2.0)
    full = cv2.resize(small, (2 * w2, 2 * h2), interpolation=cv2.INTER_LINEAR)
    full = np.pad(full, ((0, shape[0] - 2 * h2), (0, shape[1] - 2 * w2)), mode="edge")
    diff = image - full
    want = diff - np.float32(np.median(diff[::6, ::6])) + np.float32(7.5)
    none = np.zeros(0, np.int64)
    got = sk.subtract_upsampled(image, small, 7.5, 6, 2 * h2, 2 * w2, none, none, 0)
    assert got.dtype == np.float32
    np.testing.assert_allclose(got, want, atol=1e-4)


def test_background_subtracted_only_where_needed_equals_it_there() -> None:
    """With each row's span of needed pixels: the pixels within ``pad`` (a box) of them as
    without, in place, every other pixel as it was."""
    rng = np.random.default_rng(3)
    image = rng.uniform(0, 255, (120, 90)).astype(np.float32)
    small = cv2.GaussianBlur(rng.uniform(0, 60, (60, 45)).astype(np.float32), (0, 0), 2.0)
    need = np.zeros(image.shape, bool)
    need[[10, 50, 51, 52, 110], [5, 40, 42, 44, 88]] = True
    none = np.zeros(0, np.int64)
    everywhere = sk.subtract_upsampled(image, small, 7.5, 6, 120, 90, none, none, 0)
    first = np.where(need.any(axis=1), need.argmax(axis=1), 90)
    last = np.where(need.any(axis=1), 89 - need[:, ::-1].argmax(axis=1), -1)
    original = image.copy()
    got = sk.subtract_upsampled(image, small, 7.5, 6, 120, 90, first, last, 4)
    assert got is image
    near = cv2.dilate(need.astype(np.uint8), np.ones((9, 9), np.uint8)).astype(bool)
    np.testing.assert_array_equal(got[near], everywhere[near])
    # A row's span covers the columns between its marked pixels too (row 50: 36..48).
    assert (got[~near] == original[~near]).mean() > 0.95


def test_a_tube_knows_its_rows_spans(renderer) -> None:
    """``tube_band``'s spans (from ``disc_mask``) are those its mask has."""
    from service.measure.band import Band

    near = extract_stripe(renderer.render(33.0, 0), StripeParams()).xy
    tube = tube_band(near, (1024, 1376), 3, 8.0)
    assert tube is not None and tube.spans is not None
    from_mask = Band(tube.mask, tube.x0, tube.y0).row_spans()
    for got, want in zip(tube.row_spans(), from_mask, strict=True):
        np.testing.assert_array_equal(got, want)
    empty = Band(np.zeros((3, 5), bool)).row_spans()
    assert (empty[1] < empty[0]).all()


def test_the_background_is_taken_off_wherever_the_extractor_reads(renderer, monkeypatch
                                                                  ) -> None:
    """The band's background computed only near the band gives the centres of the whole
    box's (the filters, the refinement and the side balance read nothing beyond)."""
    from service.measure import stripe

    image = renderer.render(33.0, 1)
    params = StripeParams()
    near = extract_stripe(image, params).xy
    tracked = extract_stripe(image, params, near)
    whole = stripe.without_background
    monkeypatch.setattr(stripe, "without_background",
                        lambda roi, disc, level, _need, _pad: whole(roi, disc, level))
    boxed = extract_stripe(image, params, near)
    np.testing.assert_array_equal(tracked.xy, boxed.xy)
    np.testing.assert_array_equal(tracked.balance, boxed.balance)


def test_patches_are_chains_denser_than_lines() -> None:
    """``in_patch``: a chain of 40 points along 40 px is a line, 40 points in a 3 px blob a
    patch, a lone point (extent 0, counted as 1 px) is neither at density 3."""
    line = np.column_stack([np.arange(40.0), np.zeros(40)])
    blob = np.random.default_rng(1).uniform(100, 103, (40, 2))
    xy = np.vstack([line, blob, [[300.0, 300.0]]])
    labels = np.r_[np.zeros(40, np.int64), np.full(40, 40), [80]]
    got = sk.in_patch(xy, labels, 3.0)
    assert not got[:40].any() and got[40:80].all() and not got[80]


def test_inverse3_is_numpy_s_inverse() -> None:
    rng = np.random.default_rng(2)
    for _ in range(200):
        j = rng.normal(size=(50, 3))
        a = j.T @ j * rng.uniform(1e-6, 1e9)
        np.testing.assert_allclose(ck.inverse3(a), np.linalg.inv(a), rtol=1e-8)
    assert np.isinf(ck.inverse3(np.zeros((3, 3)))).all()


def test_local_parabolas_are_the_weighted_least_squares_fits() -> None:
    """``local_parabolas``: each point's ``c`` of ``v = a + b u + c u^2`` in its own tangent
    frame, Gaussian weights along the stripe, points 2 px or more off the normal left out."""
    rng = np.random.default_rng(3)
    t = np.linspace(0.0, 1.2, 80)
    xy = np.column_stack([200 * np.cos(t), 200 * np.sin(t)]) + rng.normal(0, 0.05, (80, 2))
    normal = -np.column_stack([np.cos(t), np.sin(t)])
    xy[40] += 3.0 * normal[40]  # a stray point, off its neighbours' normals
    idx = sk.nearest_neighbours(np.ascontiguousarray(xy), 15)
    got = sk.local_parabolas(xy, normal, idx, 5.0)
    for i in (3, 20, 39, 41, 70):
        rel = xy[idx[i]] - xy[i]
        u = rel @ np.array([-normal[i, 1], normal[i, 0]])
        v = rel @ normal[i]
        use = np.abs(v) < 2.0
        a = np.column_stack([np.ones(use.sum()), u[use], u[use] ** 2])
        sw = np.sqrt(np.exp(-0.5 * (u[use] / 5.0) ** 2))
        want = np.linalg.lstsq(a * sw[:, None], v[use] * sw, rcond=None)[0][2]
        assert got[i] == pytest.approx(want, rel=1e-6, abs=1e-9)


def _stats_reference(image: np.ndarray, k: int, spacing: int) -> tuple[float, float]:
    """``background_and_noise`` as its docstring has it, in numpy, block by block."""
    hb, wb = image.shape[0] // k, image.shape[1] // k
    means, variances = [], []
    for by in range(0, hb, spacing):
        for bx in range(0, wb, spacing):
            block = image[by * k:by * k + k, bx * k:bx * k + k].astype(np.float64)
            d = block[:, 1::2][:, :k // 2] - block[:, 0::2][:, :k // 2]
            means.append(block.mean())
            variances.append((d**2).sum() / (2.0 * d.size))
    means, variances = np.array(means), np.array(variances)
    dark = variances[means <= np.percentile(means, 75.0)]
    chi2 = (1.0 - 2.0 / (9.0 * k * (k // 2))) ** 3
    return float(np.median(means)), math.sqrt(np.median(dark) / chi2)


@pytest.mark.parametrize("shape", [(1024, 1376), (101, 77)])
def test_background_and_noise_are_the_block_statistics(shape: tuple[int, int]) -> None:
    rng = np.random.default_rng(shape[0])
    image = np.clip(rng.normal(20, 4, shape) + np.linspace(0, 30, shape[1]), 0, 255
                    ).astype(np.uint8)
    got = sk.background_and_noise(image, 4, 8)
    assert got == pytest.approx(_stats_reference(image, 4, 8), rel=1e-12)


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 10_000), st.integers(2, 300), st.floats(0.05, 6.3))
def test_compiled_arc_geometry_is_numpy_s(seed: int, n: int, arc: float) -> None:
    rng = np.random.default_rng(seed)
    t = rng.uniform(0.0, arc, n) + rng.uniform(-math.pi, math.pi)
    c = rng.normal(0, 2, 2)
    sec = c + 10.0 * np.column_stack([np.cos(t), np.sin(t)]) + rng.normal(0, 0.01, (n, 2))
    a = np.sort(np.arctan2(sec[:, 1] - c[1], sec[:, 0] - c[0]))
    gaps = np.diff(np.concatenate([a, [a[0] + 2 * math.pi]]))
    assert ck.arc_span(sec[:, 0].copy(), sec[:, 1].copy(), c[0], c[1]) == \
        pytest.approx(2 * math.pi - gaps.max(), abs=1e-12)
    ang, mid = sheet_kernels.arc_angles(sec, c[0], c[1])
    raw = np.arctan2(sec[:, 1] - c[1], sec[:, 0] - c[0])
    want_mid = np.arctan2(np.sin(raw).mean(), np.cos(raw).mean())
    assert mid == pytest.approx(want_mid, abs=1e-9)
    np.testing.assert_allclose(ang, want_mid + (raw - want_mid + math.pi) % (2 * math.pi)
                               - math.pi, atol=1e-9)
    pts3 = np.column_stack([sec, rng.uniform(50, 80, n)])
    radial = sec - c
    cos = -(radial * sec).sum(axis=1) / (np.hypot(*radial.T) * np.linalg.norm(pts3, axis=1))
    np.testing.assert_allclose(ck.view_cosines(sec, pts3, c[0], c[1]),
                               np.clip(cos, -1, 1), atol=1e-12)


def _ring_reference(sec: np.ndarray, c: np.ndarray, window: float, sigmas: float
                    ) -> np.ndarray:
    """``ring_consensus`` as it was written in numpy."""
    rho = np.hypot(sec[:, 0] - c[0], sec[:, 1] - c[1])
    s = np.sort(rho)
    ends = np.searchsorted(s, s + 2.0 * window, side="right")
    i = int(np.argmax(ends - np.arange(len(s))))
    radius = np.median(s[i:ends[i]])
    for _ in range(3):
        dev = np.abs(rho - radius)
        inside = dev[dev <= window]
        scatter = ck.MAD_TO_SIGMA * np.median(inside) if inside.size else math.nan
        if not sigmas * scatter > window * 1.05:
            break
        window = sigmas * scatter
    return np.abs(rho - radius) <= window


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 10_000), st.integers(1, 400), st.floats(0.005, 0.2),
       st.sampled_from([0.0, 4.0]))
def test_compiled_consensus_is_the_numpy_one(seed: int, n: int, window: float,
                                            sigmas: float) -> None:
    rng = np.random.default_rng(seed)
    t = rng.uniform(0, 2.0, n)
    r = np.where(rng.random(n) < 0.8, 15.0, rng.uniform(5, 25, n))
    sec = np.column_stack([r * np.cos(t), r * np.sin(t)]) + rng.normal(0, 0.02, (n, 2))
    c = rng.normal(0, 0.01, 2)
    inside = consensus.ring_consensus(sec, c, window, sigmas)
    np.testing.assert_array_equal(inside, _ring_reference(sec, c, window, sigmas))
    chain = rng.integers(0, max(1, n // 7), n)
    on = np.bincount(chain, weights=inside.astype(float))
    share = on[chain] / np.bincount(chain)[chain]
    want = inside & ((share >= 0.5) | (on[chain] >= 30))
    np.testing.assert_array_equal(consensus.by_chain(inside, chain), want)
