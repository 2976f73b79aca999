"""Speed of the measurement core on one core, where its time goes, and how its stripe
extractor compares on the same frames with a plain full-frame Steger and a grey-centroid
extractor.

Frames: the simulated rig at 1376x1024, ``--shafts`` shafts of 20-47 mm, ``--frames`` turning
frames of each (fresh speckle per frame; seeded), as a lathe delivers them.
- Core: ``measure_frame`` over every frame of every shaft in order, the stripe tracked from
  the previous frame of the same shaft (``near``) as the service does, the first frame of a
  shaft searched in full; method ``axis`` and ``geometric``, each repeated ``--runs`` times;
  frames per second of each run, the median reported, and the first (full-search) frames'
  time separately. OpenCV is held to one thread; run with ``OMP_NUM_THREADS=1
  OPENBLAS_NUM_THREADS=1 NUMBA_NUM_THREADS=1`` (``make bench`` does).
- A frame checked for a reflection beside the stripe (``MeasureParams.reflection_check``,
  which the service asks a few times a second): its median time, one run.
- Stages: the time spent in each step of ``measure_frame`` (``axis``, tracked), ms per frame.
- Extractors: ours (tracked, as the core runs it), plain Steger (``plain_steger``: OpenCV's
  filters over the whole frame and Steger's test at every pixel, as fast as plain can be:
  the yardstick of the core's ratios), the same pruned by the strength test before the
  eigenvector (``plain_steger_pruned``), grey centroid (per column,
  the intensity-weighted centre of the pixels above half the column's peak). Each
  extractor's points go through the same triangulation and the same ``geometric`` fit; time
  per frame (median over the runs) and mean |diameter error| per frame are reported.

Run: ``.venv/bin/python -m tests.bench.core_throughput [--shafts N] [--frames M] [--runs R]``.
"""

from __future__ import annotations

import argparse
import math
import statistics
import time
from collections import defaultdict
from collections.abc import Callable
from dataclasses import replace

import cv2
import numpy as np

from drivers.sim.rig import RigConfig, ShaftRenderer
from service.measure import diameter
from service.measure.diameter import (
    MeasureParams,
    drop_grazing,
    fit_section,
    measure_frame,
    section_points,
)
from service.measure.geometry import RigGeometry, geometry_of
from service.measure.result import Method, Status
from service.measure.stripe import StripeParams, StripePoints, extract_stripe
from tests.bench.plain_steger import plain_steger, plain_steger_pruned
from tests.bench.results import save_report


def grey_centroid(image: np.ndarray, _: StripeParams) -> StripePoints:
    """Per column: the intensity-weighted row of the pixels above half the column's peak."""
    img = image.astype(np.float32)
    background = float(np.median(img))
    img = np.clip(img - background, 0, None)
    peak = img.max(axis=0)
    keep = peak > 20.0
    w = np.where(img >= 0.5 * peak[None, :], img, 0.0)
    s = w.sum(axis=0)
    rows = np.arange(img.shape[0], dtype=np.float64)[:, None]
    y = (w * rows).sum(axis=0) / np.where(s > 0, s, 1.0)
    x = np.arange(img.shape[1], dtype=np.float64)
    xy = np.column_stack([x[keep], y[keep]])
    n = len(xy)
    return StripePoints(xy, np.tile([0.0, 1.0], (n, 1)), peak[keep].astype(np.float64),
                        np.ones(n), background, 1.0)


Sequence = list[tuple[np.ndarray, float]]


WIDE_RIG = {"sheet_sigma_mm": 0.12, "speckle_grain_px": 1.6}
"""A thick light sheet and coarse speckle: the stripe is found with wider filters."""


def sequences(shafts: int, frames: int, seed: int, **rig_kw: float
              ) -> tuple[list[Sequence], ShaftRenderer]:
    rig = ShaftRenderer(RigConfig(**rig_kw), seed=seed)
    rng = np.random.default_rng(seed)
    out = []
    for k, d in enumerate(rng.uniform(20.0, 47.0, shafts)):
        out.append([(rig.render(d, k * 1000 + i), d) for i in range(frames)])
    return out, rig


def run_core(data: list[Sequence], geometry: RigGeometry, method: Method,
             params: MeasureParams) -> tuple[float, float, list[float], list[float]]:
    """Frames per second over all frames, ms of the first (full-search) frames, |errors|, and
    every frame's ms."""
    first_ms, errors, each_ms = [], [], []
    t0 = time.perf_counter()
    for seq in data:
        near = scale = None
        for i, (image, d) in enumerate(seq):
            t1 = time.perf_counter()
            m = measure_frame(image, geometry, method, params, near=near, scale_px=scale)
            each_ms.append((time.perf_counter() - t1) * 1000.0)
            if i == 0:
                first_ms.append(each_ms[-1])
            near = m.stripe_px
            scale = m.filter_px if near is not None else None
            if m.status is Status.OK:
                errors.append(abs(m.diameter_mm - d) * 1000.0)
    fps = sum(len(s) for s in data) / (time.perf_counter() - t0)
    return fps, statistics.median(first_ms), errors, each_ms


STAGES = ["extract_stripe", "section_points", "drop_grazing", "_fit_circle",
          "correct_sheet_bias"]


def core_row(data: list[Sequence], geometry: RigGeometry, method: Method,
             params: MeasureParams, runs: int) -> dict:
    """The core's figures over ``runs`` runs of every frame: medians."""
    results = [run_core(data, geometry, method, params) for _ in range(runs)]
    fps = [r[0] for r in results]
    return {"fps_one_core": statistics.median(fps), "fps_runs": fps,
            "ms_per_frame": 1000.0 / statistics.median(fps),
            "first_frame_ms": statistics.median(r[1] for r in results),
            # The median frame over every frame of every run: what a tracked frame costs.
            "median_frame_ms": statistics.median(t for r in results for t in r[3]),
            "mean_abs_error_um": float(np.mean(results[0][2])) if results[0][2] else None,
            "measured": len(results[0][2])}


def stage_times(data: list[Sequence], geometry: RigGeometry, params: MeasureParams
                ) -> dict[str, float]:
    """ms per frame in each step of ``measure_frame`` (axis, tracked); the rest is 'other'."""
    spent: dict[str, float] = defaultdict(float)
    originals = {name: getattr(diameter, name) for name in STAGES}

    def timed(name: str, fn: Callable) -> Callable:
        def wrapper(*args: object, **kwargs: object) -> object:
            t = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                spent[name] += time.perf_counter() - t
        return wrapper

    for name, fn in originals.items():
        setattr(diameter, name, timed(name, fn))
    try:
        t0 = time.perf_counter()
        run_core(data, geometry, Method.AXIS, params)
        total = time.perf_counter() - t0
    finally:
        for name, fn in originals.items():
            setattr(diameter, name, fn)
    n = sum(len(s) for s in data)
    out = {name: spent[name] / n * 1000.0 for name in STAGES}
    out["fit (both fits, all rounds)"] = out.pop("_fit_circle")
    out["other"] = (total - sum(spent.values())) / n * 1000.0
    out["total"] = total / n * 1000.0
    return out


def tracked_ours(seq: Sequence, params: StripeParams) -> list[StripePoints]:
    found, near = [], None
    for image, _d in seq:
        st = extract_stripe(image, params, near)
        near = st.xy if st else None
        found.append(st)
    return found


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shafts", type=int, default=5)
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--seed", type=int, default=21)
    ap.add_argument("--json", default="bench-results/core_throughput.json")
    args = ap.parse_args()
    cv2.setNumThreads(1)
    data, rig = sequences(args.shafts, args.frames, args.seed)
    geometry = geometry_of(rig.calibration)
    # As the service measures a frame between its reflection checks (a few a second, timed
    # on their own below).
    params = MeasureParams(reflection_check=False)
    n_frames = sum(len(s) for s in data)
    out: dict = {"shafts": args.shafts, "frames_per_shaft": args.frames, "runs": args.runs,
                 "seed": args.seed, "image_size": list(rig.config.image_size), "core": {},
                 "extractors": {}}
    run_core(data[:1], geometry, Method.AXIS, params)  # warm caches and compiled code
    for method in (Method.AXIS, Method.GEOMETRIC):
        out["core"][method.value] = core_row(data, geometry, method, params, args.runs)
    wide, wide_rig = sequences(args.shafts, args.frames, args.seed, **WIDE_RIG)
    wide_geometry = geometry_of(wide_rig.calibration)
    run_core(wide[:1], wide_geometry, Method.AXIS, params)
    out["core"]["axis, wide sheet"] = core_row(wide, wide_geometry, Method.AXIS, params,
                                               args.runs)
    out["wide_rig"] = WIDE_RIG
    checked = run_core(data, geometry, Method.AXIS, replace(params, reflection_check=True))
    out["reflection_check"] = {
        "median_frame_ms": statistics.median(checked[3]),
        "mean_abs_error_um": float(np.mean(checked[2])) if checked[2] else None,
        "extra_ms": statistics.median(checked[3]) - out["core"]["axis"]["median_frame_ms"]}
    out["stages_ms"] = stage_times(data, geometry, params)
    flat = [(image, d) for seq in data for image, d in seq]
    plain_data = flat[:: max(1, len(flat) // 20)]  # 20 frames are plenty for a 200 ms one
    extractors: dict[str, tuple[Callable, list]] = {
        "ours": (None, flat), "plain_steger": (plain_steger, plain_data),
        "plain_steger_pruned": (plain_steger_pruned, plain_data),
        "grey_centroid": (grey_centroid, flat)}
    # The extractors are compared by the free circle through their points, every one fitted
    # (none refused as uncertain, as the paper's comparison does).
    compare = replace(params, max_uncertainty_mm=math.inf)
    for name, (extract, frames) in extractors.items():
        times, errors, failed = [], [], 0
        for run in range(args.runs):
            t0 = time.perf_counter()
            if extract is None:
                found = [st for seq in data for st in tracked_ours(seq, params.stripe)]
            else:
                found = [extract(image, params.stripe) for image, _d in frames]
            times.append((time.perf_counter() - t0) / len(frames) * 1000.0)
            if run:
                continue
            for stripe, (_image, d) in zip(found, frames, strict=True):
                m = None
                if stripe:
                    pts = drop_grazing(section_points(stripe, geometry), geometry, params)
                    if len(pts.section) >= params.min_points:
                        m = fit_section(pts, geometry, Method.GEOMETRIC, compare)
                if m:
                    errors.append(abs(m.diameter_mm - d) * 1000.0)
                else:
                    failed += 1
        out["extractors"][name] = {
            "frames": len(frames), "ms_per_frame": statistics.median(times),
            "mean_abs_error_um": float(np.mean(errors)) if errors else None,
            "failed": failed}
    plain = out["extractors"]["plain_steger"]["ms_per_frame"]
    for v in out["extractors"].values():
        v["plain_vs_this"] = plain / v["ms_per_frame"]
    for v in out["core"].values():
        v["plain_steger_vs_core"] = plain / v["ms_per_frame"]
        v["plain_steger_vs_median_frame"] = plain / v["median_frame_ms"]
    print(f"{args.shafts} shafts x {args.frames} frames of {rig.config.image_size[0]}x"
          f"{rig.config.image_size[1]} (20-47 mm, seed {args.seed}), {args.runs} runs, "
          f"medians, one core\n")
    print("frames/s and ms/frame over all frames (each shaft's first, full-search frame in);"
          " the median frame, and the plain Steger's ms over each")
    print(f"{'core':>16} {'frames/s':>9} {'ms/frame':>9} {'median ms':>10} {'1st frame ms':>13} "
          f"{'plain/core':>10} {'plain/median':>12} {'mean|err| um':>13}")
    for name, v in out["core"].items():
        print(f"{name:>16} {v['fps_one_core']:9.1f} {v['ms_per_frame']:9.2f} "
              f"{v['median_frame_ms']:10.2f} {v['first_frame_ms']:13.1f} "
              f"{v['plain_steger_vs_core']:10.1f} {v['plain_steger_vs_median_frame']:12.1f} "
              + (f"{v['mean_abs_error_um']:13.2f}" if v["mean_abs_error_um"] is not None
                 else f"{'- (' + str(v['measured']) + ' ok)':>13}"))
    rc = out["reflection_check"]
    print(f"\na frame checked for a reflection (axis, tracked, one run): median "
          f"{rc['median_frame_ms']:.2f} ms, {rc['extra_ms']:.2f} ms more; at 5 checks a "
          f"second {rc['extra_ms'] * 5 / 10:.1f} % of a core")
    print("\nwhere the time goes (axis, tracked), ms per frame:")
    for name, v in out["stages_ms"].items():
        print(f"  {name:>28} {v:7.3f}")
    print(f"\n{'extractor':>14} {'frames':>6} {'ms/frame':>9} {'plain/this':>10} "
          f"{'mean|err| um':>13} {'failed':>6}")
    for name, v in out["extractors"].items():
        err = "-" if v["mean_abs_error_um"] is None else f"{v['mean_abs_error_um']:.1f}"
        print(f"{name:>14} {v['frames']:6d} {v['ms_per_frame']:9.2f} {v['plain_vs_this']:10.1f} "
              f"{err:>13} {v['failed']:6d}")
    assert n_frames == len(flat)
    save_report(out, "core_throughput", path=args.json)


if __name__ == "__main__":
    main()
