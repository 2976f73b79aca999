"""Robustness on the shop floor: every disturbance family of ``drivers.sim.disturb``, measured
by ``axis`` and ``geometric``.

Per family and method: frames measured (%), mean and max |error| (um) of the measured frames,
frames more than 20 um off (the number that must be 0: a frame that cannot be trusted must be
refused), and the refusals' reasons. Each frame is measured on its own (no tracking), on three
diameters, with fresh speckle, noise and disturbances per frame.

The development settings (``FAMILIES``) and seeds are what the extractor was tuned on;
``--held-out`` scores the held-out settings (``HELD_OUT``) on other seeds instead, which are
only run at the end of a piece of work.

Run: ``.venv/bin/python -m tests.bench.robustness [--frames N] [--held-out] [--json FILE]``.
"""

from __future__ import annotations

import argparse
import collections
import time

import numpy as np

from drivers.sim.disturb import FAMILIES, HELD_OUT, Disturbances
from drivers.sim.rig import RigConfig, ShaftRenderer
from service.measure.diameter import measure_frame
from service.measure.geometry import geometry_of
from service.measure.result import Method, Status
from tests.bench.results import save_report

DIAMETERS_MM = (21.7, 30.0, 44.0)
METHODS = (Method.AXIS, Method.GEOMETRIC)
LIMIT_UM = 20.0
DEV_SEEDS = (11, 12, 13)
HELD_OUT_SEEDS = (901, 902, 903)


def score_family(spec: Disturbances, frames: int, seeds: tuple[int, ...],
                 base: RigConfig | None = None) -> dict[str, dict]:
    """Measure ``frames`` frames per diameter and seed under ``spec``; per method the
    figures of the module's docstring."""
    cfg = (base or RigConfig()).with_(disturbances=spec)
    errors: dict[str, list[float]] = {m.value: [] for m in METHODS}
    refused: dict[str, collections.Counter] = {m.value: collections.Counter()
                                               for m in METHODS}
    total = 0
    for seed in seeds:
        renderer = ShaftRenderer(cfg, seed=seed)
        geometry = geometry_of(renderer.calibration)
        for k, d in enumerate(DIAMETERS_MM):
            for i in range(frames):
                img = renderer.render(d, k * 1000 + i)
                total += 1
                for method in METHODS:
                    m = measure_frame(img, geometry, method)
                    if m.status is Status.OK:
                        errors[method.value].append((m.diameter_mm - d) * 1000.0)
                    else:
                        refused[method.value][m.status.value] += 1
    out = {}
    for method in METHODS:
        e = np.abs(np.array(errors[method.value]))
        out[method.value] = {
            "frames": total, "measured_pct": 100.0 * e.size / total,
            "mean_abs_um": float(e.mean()) if e.size else float("nan"),
            "max_abs_um": float(e.max()) if e.size else float("nan"),
            "over_limit": int((e > LIMIT_UM).sum()),
            "refused": dict(refused[method.value]),
        }
    return out


def main() -> None:
    """Score every family and print and save the table."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=6, help="frames per diameter and seed")
    ap.add_argument("--held-out", action="store_true",
                    help="score the held-out settings and seeds (only at the end)")
    ap.add_argument("--family", action="append", help="only these families")
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    families = dict(FAMILIES) if not args.held_out else {"clean": Disturbances(),
                                                               **HELD_OUT}
    if args.family:
        families = {k: v for k, v in families.items() if k in args.family}
    seeds = HELD_OUT_SEEDS if args.held_out else DEV_SEEDS
    t0 = time.perf_counter()
    report: dict = {"held_out": args.held_out, "seeds": seeds, "frames_per_diameter":
                    args.frames, "diameters_mm": DIAMETERS_MM, "families": {}}
    print(f"{'held-out' if args.held_out else 'development'} settings, seeds {seeds}, "
          f"{args.frames} frames x {len(DIAMETERS_MM)} diameters per seed")
    print(f"{'family':>12} {'method':>9} {'measured':>8} {'mean|e|':>8} {'max|e|':>7} "
          f"{'>20um':>5}  refused")
    for name, spec in families.items():
        res = score_family(spec, args.frames, seeds)
        report["families"][name] = res
        for method, r in res.items():
            why = ", ".join(f"{k} {v}" for k, v in sorted(r["refused"].items()))
            print(f"{name:>12} {method:>9} {r['measured_pct']:7.1f}% {r['mean_abs_um']:8.2f} "
                  f"{r['max_abs_um']:7.1f} {r['over_limit']:5d}  {why}")
    report["seconds"] = time.perf_counter() - t0
    save_report(report, "robustness", args.held_out, args.json)


if __name__ == "__main__":
    main()
