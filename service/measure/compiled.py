"""Compile the core's numba kernels ahead of the first frame.

numba compiles a kernel the first time it is called with a given type of argument and keeps
the machine code in ``__pycache__``; on a fresh checkout the first calls take about 45 s.
``python -m service.measure.compiled`` (run by ``make run``, ``make test`` and ``make bench``:
two processes at once, 28 s) and the service's start call ``compile_kernels`` so that no
frame, and no test with a deadline, waits for it.
"""

from __future__ import annotations

import multiprocessing
import os
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from service.measure import circle_kernels, consensus, fit, sheet_kernels
from service.measure.stripe import extract_stripe
from service.measure.triangulate import intersect_plane


def _ring(dtype: type, scale: float) -> np.ndarray:
    """A bright ring of radius 60 px on a dark ground, sigma 1.2 px."""
    yy, xx = np.mgrid[0:160, 0:180].astype(np.float64)
    r = np.hypot(xx - 90.3, yy - 80.6)
    img = 6.0 + 150.0 * np.exp(-0.5 * ((r - 60.0) / 1.2) ** 2)
    img += np.random.default_rng(0).normal(0.0, 1.5, img.shape)
    return np.clip(img * scale, 0, np.iinfo(dtype).max).astype(dtype)


def _compile_stripe() -> np.ndarray:
    """The stripe extractor's kernels (most of the compile time), 8- and 16-bit images."""
    found = None
    for dtype, scale in ((np.uint8, 1.0), (np.uint16, 257.0)):
        image = _ring(dtype, scale)
        found = extract_stripe(image)
        extract_stripe(image, near=found.xy)
    return found.xy


def _compile_fits(xy: np.ndarray | None = None) -> None:
    """The fits', the sheet correction's and the consensus's kernels."""
    if xy is None:  # the ring's stripe, as the extractor finds it, without compiling it
        a = np.linspace(0.0, 2.0 * np.pi, 400, endpoint=False)
        xy = np.column_stack([90.3 + 60.0 * np.cos(a), 80.6 + 60.0 * np.sin(a)])
    pts = (xy - [90.3, 80.6]) * 0.01
    free = fit.fit_geometric(pts)
    fit.fit_axis_prior(pts, np.zeros(2), 0.001, start=free)
    fit.circle_covariance(pts, free.center, free.radius, center_prior_sigma=0.001)
    fit.arc_variance(pts, free.center, free.inliers, np.ones(len(pts)))
    ones = np.ones(len(pts))
    sheet_kernels.light_coefficients(pts, 0.0, 0.0, ones, np.eye(2))
    sheet_kernels.profile_sigma(ones, ones, ones, 12, 0.5)
    sheet_kernels.arc_angles(pts, 0.0, 0.0)
    fit.arc_span_deg(pts, np.zeros(2))
    intersect_plane(pts, np.array([0.0, 0.0, 1.0]), 100.0)
    inside = consensus.ring_consensus(pts, np.zeros(2), 0.05)
    consensus.by_chain(inside, np.zeros(len(pts), np.int64))
    circle_kernels.view_cosines(pts, np.column_stack([pts, ones]), 0.0, 0.0)


def compile_kernels() -> float:
    """Run every kernel once for 8- and 16-bit images; returns the seconds it took."""
    t0 = time.perf_counter()
    _compile_fits(_compile_stripe())
    return time.perf_counter() - t0


def compile_in_parallel() -> float:
    """``compile_kernels`` with the extractor's kernels and the others compiled at once in
    two processes (disjoint sets: neither compiles what the other does), when there are two
    cores (a fresh checkout's 45 s became 28); returns the seconds it took."""
    t0 = time.perf_counter()
    if (os.cpu_count() or 1) < 2:
        return compile_kernels()
    with ProcessPoolExecutor(2, mp_context=multiprocessing.get_context("spawn")) as pool:
        jobs = [pool.submit(_compile_stripe), pool.submit(_compile_fits)]
        for job in jobs:
            job.result()
    compile_kernels()  # from the cache now: what a process of the gauge does at its start
    return time.perf_counter() - t0


if __name__ == "__main__":
    print(f"measurement kernels ready ({compile_in_parallel():.1f} s)")
