"""Accuracy across rigs, not one: ``axis`` over a range of light-sheet thicknesses, speckle
grains and speckle contrasts (issue #16, item 3).

Per row (one rig setting; the others at the simulator's defaults), three diameters (21.7, 30
and 44 mm), ``--frames`` frames each (60), each frame measured on its own with the
calibration's axis (no mastering):

- frames measured (%), the per-frame mean |error| and mean error (um);
- fused: each diameter's frames in windows of 20, each window fused; the mean and the largest
  |error| of the fused values (um);
- the speckle floor (``tests.bench.speckle_floor``): the per-frame mean |error| that the
  speckle alone gives the stripe's own light, whatever the extractor, and the fused floor
  that implies for 20 frames (its standard deviation over sqrt 20, times sqrt(2/pi));
- the honesty of the reported uncertainty: the standard deviation of the z-scores
  (error / uncertainty). The measurement's prior says the axis is known to 1 um
  (``MeasureParams.axis_sigma_mm``, the axis after mastering), while the simulated
  calibration is exact: the first z column measures each frame again on a rig whose shaft
  axis is off the calibrated one by a draw from that prior (each frame its own draw, both
  directions), the second the exact rig with a prior as exact as it (0.01 um). 1 is
  honest.

``--held-out`` scores other seeds and diameters and three settings between and beyond the
development rows, only at the end of a piece of work.

Run: ``.venv/bin/python -m tests.bench.rig_range [--frames N] [--held-out] [--json FILE]``.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from drivers.sim.rig import RigConfig, ShaftRenderer
from service.measure.diameter import MeasureParams, measure_frame
from service.measure.fuse import fuse
from service.measure.geometry import geometry_of
from service.measure.result import Method
from tests.bench import speckle_floor
from tests.bench.results import save_report

ROWS: dict[str, dict[str, float]] = {
    "sheet 0.03 mm": {"sheet_sigma_mm": 0.03},
    "sheet 0.06 mm": {"sheet_sigma_mm": 0.06},
    "sheet 0.10 mm": {"sheet_sigma_mm": 0.10},
    "sheet 0.15 mm": {"sheet_sigma_mm": 0.15},
    "grain 0.8 px": {"speckle_grain_px": 0.8},
    "grain 2.0 px": {"speckle_grain_px": 2.0},
    "contrast 0.1": {"speckle_contrast": 0.1},
    "contrast 0.5": {"speckle_contrast": 0.5},
}
HELD_OUT_ROWS: dict[str, dict[str, float]] = {
    "sheet 0.12, grain 1.6": {"sheet_sigma_mm": 0.12, "speckle_grain_px": 1.6},
    "sheet 0.04, contrast 0.4": {"sheet_sigma_mm": 0.04, "speckle_contrast": 0.4},
    "grain 1.0, contrast 0.35, 40 deg": {"speckle_grain_px": 1.0, "speckle_contrast": 0.35,
                                         "triangulation_deg": 40.0},
}
DIAMETERS_MM = (21.7, 30.0, 44.0)
HELD_OUT_DIAMETERS_MM = (18.3, 36.5)


FUSED_FRAMES = 20


def score_row(changes: dict[str, float], diameters: tuple[float, ...], frames: int,
              seed: int) -> dict[str, float]:
    """The row's figures (see the module's docstring)."""
    errs, zs, zs_exact, fused_errs, floor, total = [], [], [], [], [], 0
    params = MeasureParams()
    exact_axis = MeasureParams(axis_sigma_mm=1e-5)
    draws = np.random.default_rng(seed)
    for k, d in enumerate(diameters):
        config = RigConfig().with_(**changes)
        r = ShaftRenderer(config, seed=seed + k)
        g = geometry_of(r.calibration)
        ms = []
        for i in range(frames):
            img = r.render(d, i)
            m = measure_frame(img, g, Method.AXIS, params)
            total += 1
            if m:
                ms.append(m)
                errs.append((m.diameter_mm - d) * 1e3)
            m = measure_frame(img, g, Method.AXIS, exact_axis)
            if m:
                zs_exact.append((m.diameter_mm - d) / m.uncertainty_mm)
            # The same frame of a shaft whose axis is off by a draw from the prior.
            off = ShaftRenderer(config.with_(axis_offset_mm=tuple(
                draws.normal(0.0, params.axis_sigma_mm, 2))), seed=seed + k)
            m = measure_frame(off.render(d, i), g, Method.AXIS, params)
            if m:
                zs.append((m.diameter_mm - d) / m.uncertainty_mm)
            if (i + 1) % FUSED_FRAMES == 0:
                f = fuse(ms)
                if f:
                    fused_errs.append(abs(f.diameter_mm - d) * 1e3)
                ms = []
        floor.extend(speckle_floor.floor_um(speckle_floor.diameter_shifts_um(r, d, frames)))
    e, fl = np.abs(np.array(errs)), np.array(floor)
    return {"measured_pct": 100.0 * len(errs) / max(total, 1),
            "mean_abs_um": float(e.mean()) if e.size else float("nan"),
            "bias_um": float(np.mean(errs)) if errs else float("nan"),
            "fused_mean_abs_um": float(np.mean(fused_errs)) if fused_errs else float("nan"),
            "fused_max_abs_um": float(np.max(fused_errs)) if fused_errs else float("nan"),
            "floor_mean_abs_um": float(np.abs(fl).mean()),
            "floor_fused_um": float(fl.std() / np.sqrt(FUSED_FRAMES) * np.sqrt(2 / np.pi)),
            "z_std": float(np.std(zs)) if len(zs) > 1 else float("nan"),
            "z_std_exact_axis": float(np.std(zs_exact)) if len(zs_exact) > 1 else float("nan")}


def main() -> None:
    """Score every row and print and save the table."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=60,
                    help=f"frames per diameter (fused in windows of {FUSED_FRAMES})")
    ap.add_argument("--held-out", action="store_true")
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    rows, diameters, seed = (HELD_OUT_ROWS, HELD_OUT_DIAMETERS_MM, 7000) if args.held_out \
        else (ROWS, DIAMETERS_MM, 300)
    t0 = time.perf_counter()
    print(f"{'held-out' if args.held_out else 'development'} rows, diameters {diameters} mm, "
          f"{args.frames} frames each, axis")
    print(f"{'row':>34} {'measured':>8} {'mean|e|':>8} {'bias':>6} {'fused':>6} "
          f"{'fused max':>9} {'floor':>6} {'fused floor':>11} {'z std':>6} "
          f"{'z, exact axis':>13}")
    report: dict = {"held_out": args.held_out, "frames": args.frames,
                    "diameters_mm": diameters, "rows": {}}
    for name, changes in rows.items():
        s = score_row(changes, diameters, args.frames, seed)
        report["rows"][name] = s
        print(f"{name:>34} {s['measured_pct']:7.1f}% {s['mean_abs_um']:8.2f} "
              f"{s['bias_um']:6.2f} {s['fused_mean_abs_um']:6.2f} {s['fused_max_abs_um']:9.2f} "
              f"{s['floor_mean_abs_um']:6.2f} {s['floor_fused_um']:11.2f} {s['z_std']:6.2f} "
              f"{s['z_std_exact_axis']:13.2f}")
    report["seconds"] = time.perf_counter() - t0
    save_report(report, "rig_range", args.held_out, args.json)


if __name__ == "__main__":
    main()
