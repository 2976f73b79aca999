"""Speed of the measurement core on one core, and how its stripe extractor compares on the
same frames with a plain full-frame Steger and a grey-centroid extractor.

Frames: the simulated rig at 1376x1024, shafts of 20-47 mm, ``--frames`` of them (seeded).
- Core: ``measure_frame`` (method ``axis``) over every frame, repeated ``--runs`` times; frames
  per second of each run, the median reported. OpenCV is held to one thread here; run it
  with ``OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1`` (``make bench`` does) for numpy's BLAS.
- Extractors: ours (coarse band, Steger in the band, weak-point rejection, chain linking,
  curvature-bias correction), plain Steger (the same Hessian filter over the whole frame with
  the same acceptance test, nothing else), grey centroid (per column, the intensity-weighted
  centre of the pixels above half the column's peak). Each extractor's points go through the
  same triangulation and the same ``geometric`` fit; time per frame (median over the runs) and
  mean |diameter error| per frame are reported.

Run: ``.venv/bin/python -m tests.bench.core_throughput [--frames N] [--runs R]``.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

from drivers.sim.rig import RigConfig, ShaftRenderer
from service.measure.diameter import (
    MeasureParams,
    drop_grazing,
    fit_section,
    measure_frame,
    section_points,
)
from service.measure.geometry import geometry_of
from service.measure.result import Method
from service.measure.stripe import (
    StripeParams,
    StripePoints,
    extract_stripe,
    reject_weak,
    steger_centres,
)


def plain_steger(image: np.ndarray, params: StripeParams) -> StripePoints:
    """Steger's centres over the whole frame with his acceptance test, nothing more."""
    img = image.astype(np.float32)
    background = float(np.median(img))
    noise = float(1.4826 * np.median(np.abs(img - background))) or 1.0
    return reject_weak(steger_centres(img, None, params, background, noise), params)


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


EXTRACTORS: dict[str, Callable[[np.ndarray, StripeParams], StripePoints]] = {
    "ours": extract_stripe, "plain_steger": plain_steger, "grey_centroid": grey_centroid}


def frames(n: int, seed: int) -> tuple[list[tuple[np.ndarray, float]], ShaftRenderer]:
    rig = ShaftRenderer(RigConfig(), seed=seed)
    rng = np.random.default_rng(seed)
    return [(rig.render(d, i), d) for i, d in enumerate(rng.uniform(20.0, 47.0, n))], rig


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--seed", type=int, default=21)
    ap.add_argument("--json", default="bench-results/core_throughput.json")
    args = ap.parse_args()
    cv2.setNumThreads(1)
    data, rig = frames(args.frames, args.seed)
    geometry = geometry_of(rig.calibration)
    params = MeasureParams()
    core_fps = []
    for _ in range(args.runs):
        t0 = time.perf_counter()
        for image, _d in data:
            measure_frame(image, geometry, Method.AXIS, params)
        core_fps.append(len(data) / (time.perf_counter() - t0))
    out: dict = {"frames": args.frames, "runs": args.runs, "seed": args.seed,
                 "image_size": list(rig.config.image_size),
                 "core_fps_one_core": statistics.median(core_fps),
                 "core_fps_runs": core_fps, "extractors": {}}
    for name, extract in EXTRACTORS.items():
        times, errors, failed = [], [], 0
        for run in range(args.runs):
            t0 = time.perf_counter()
            found = [extract(image, params.stripe) for image, _d in data]
            times.append((time.perf_counter() - t0) / len(data) * 1000.0)
            if run:
                continue
            for stripe, (_image, d) in zip(found, data, strict=True):
                m = None
                if stripe:
                    pts = drop_grazing(section_points(stripe, geometry), geometry, params)
                    if len(pts.section) >= params.min_points:
                        m = fit_section(pts, geometry, Method.GEOMETRIC, params)
                if m:
                    errors.append(abs(m.diameter_mm - d) * 1000.0)
                else:
                    failed += 1
        out["extractors"][name] = {
            "ms_per_frame": statistics.median(times),
            "mean_abs_error_um": float(np.mean(errors)) if errors else None,
            "failed": failed}
    ours = out["extractors"]["ours"]["ms_per_frame"]
    for v in out["extractors"].values():
        v["time_vs_ours"] = v["ms_per_frame"] / ours
    print(f"{args.frames} frames of {rig.config.image_size[0]}x{rig.config.image_size[1]} "
          f"(shafts 20-47 mm, seed {args.seed}), {args.runs} runs, medians\n")
    print(f"measurement core (axis), one core: {out['core_fps_one_core']:.1f} frames/s\n")
    print(f"{'extractor':>14} {'ms/frame':>9} {'x ours':>7} {'mean|err| um':>13} {'failed':>6}")
    for name, v in out["extractors"].items():
        err = "-" if v["mean_abs_error_um"] is None else f"{v['mean_abs_error_um']:.1f}"
        print(f"{name:>14} {v['ms_per_frame']:9.1f} {v['time_vs_ours']:7.2f} {err:>13} "
              f"{v['failed']:6d}")
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json).write_text(json.dumps(out, indent=2))
    print(f"\nWritten {args.json}")


if __name__ == "__main__":
    main()
