"""The service's frame path on turning surfaces off the spindle axis and out of round: each
frame's prior (``pipeline.frame_prior``), its measurement, and the publisher's judgement
(``publish.judged``: the concentricity watch, the run-out tracker, the axis tracker) in frame
order, as an encoder-triggered camera delivers them; the roundness of the frames kept
(``FormFrames``). Scored per case against the simulator's truth: per-frame diameter error
(mean and largest |error|, largest |error| over its uncertainty), refusals, TIR and RONt
errors, the lobes found.

    python -m tests.bench.turning_service [--frames 160] [--seeds 21,22] [--held-out]

Tuning seeds (21, 22) and a held-out set (seeds 901, 902 with the rig's physics varied: a
thicker sheet, coarser speckle, other diameters and steps) that only the final run scores.
"""

from __future__ import annotations

import argparse
import math
import time
from dataclasses import dataclass, replace

import numpy as np

from calib_store.store import CalibrationInfo
from drivers.sim.rig import RigConfig, ShaftRenderer, Turning
from service.measure.axis_track import AxisTracker
from service.measure.diameter import MeasureParams, axis_center, measure_frame
from service.measure.form import ConcentricityWatch
from service.measure.geometry import geometry_of
from service.measure.result import Method, Status
from service.measure.runout_track import RunoutTracker, SpindleAngles
from service.runtime.calibration import CalibrationInUse
from service.runtime.pipeline import RUNOUT_FREE_FIT_HZ, frame_prior
from service.runtime.publish import judged
from tests.bench.results import save_report


@dataclass(frozen=True)
class Case:
    name: str
    eccentricity_mm: float
    lobes: tuple[tuple[int, float, float], ...]
    step_deg: float
    diameter_mm: float = 30.0


TUNING = [
    Case("concentric, round", 0.0, (), 37.0),
    Case("30 um off", 0.030, (), 37.0),
    Case("100 um off", 0.100, (), 23.0),
    Case("50 um off, 3 lobes of 4 um", 0.050, ((3, 0.004, 20.0),), 37.0),
    Case("20 um off, 2 lobes of 2.5 um", 0.020, ((2, 0.0025, 70.0),), 41.0),
    Case("60 um off, locked to the spindle", 0.060, (), 360.0),
]

HELD_OUT = [
    Case("concentric, round", 0.0, (), 29.0, 27.5),
    Case("45 um off", 0.045, (), 29.0, 27.5),
    Case("90 um off", 0.090, (), 17.0, 32.0),
    Case("70 um off, 5 lobes of 1.5 um", 0.070, ((5, 0.0015, 200.0),), 29.0, 27.5),
    Case("10 um off, 4 lobes of 5 um", 0.010, ((4, 0.005, 10.0),), 43.0, 32.0),
    Case("35 um off, 7 lobes of 1 um", 0.035, ((7, 0.001, 0.0),), 31.0, 27.5),
    Case("80 um off, locked to the spindle", 0.080, (), 720.0, 27.5),
    # Added on 6 December, after the cases above had been scored: the range of lobes
    # (2-10 um, 2-7 of them), which the two small-lobed cases above lie below.
    Case("60 um off, 2 lobes of 2 um", 0.060, ((2, 0.002, 120.0),), 29.0, 27.5),
    Case("25 um off, 3 lobes of 8 um", 0.025, ((3, 0.008, 300.0),), 31.0, 32.0),
    Case("concentric, 6 lobes of 3 um", 0.0, ((6, 0.003, 45.0),), 43.0, 27.5),
    Case("100 um off, 7 lobes of 2 um", 0.100, ((7, 0.002, 250.0),), 17.0, 32.0),
]

WARM_UP = 40
"""Frames before scoring: the run-out is learnt in the first revolution (its frames are
judged by the concentricity watch meanwhile, and counted apart)."""

FORM_EVERY = 40
"""The form made again every this many frames (the service: every 2 s; 200 frames at 100
frames a second, but the bench's cases are short)."""

FREE_EVERY = max(1, round(100.0 / RUNOUT_FREE_FIT_HZ))
"""Once the position is settled, a free fit every this many frames at 100 frames a second, as
the service with the spindle's angle (``pipeline.RUNOUT_FREE_FIT_HZ``; every frame until
then)."""


def run_case(case: Case, seed: int, frames: int, rig: RigConfig) -> dict:
    turning = Turning(case.eccentricity_mm, 40.0 + 17.0 * seed % 360, case.lobes)
    renderer = ShaftRenderer(replace(rig, turning=turning), seed=seed)
    cal = renderer.calibration
    geometry = geometry_of(cal)
    c0 = axis_center(geometry)
    info = CalibrationInfo(1, 0.0, "bench", "", True, None)
    in_use = CalibrationInUse(info, cal, geometry, None, AxisTracker(c0, 0.001),
                              ConcentricityWatch(), RunoutTracker())
    angles = SpindleAngles(case.step_deg)
    base = MeasureParams()
    params = {free: replace(base, free_fit=free) for free in (False, True)}
    errors, sigmas, refused, early = [], [], 0, 0
    near = None
    for i in range(frames):
        image = renderer.render(case.diameter_mm, i, spindle_deg=angles.at(i))
        prior, spindle = frame_prior(i, in_use, angles)
        free = not in_use.settling.settled or i % FREE_EVERY == 0
        m = measure_frame(image, geometry, Method.AXIS, params[free], prior, near)
        near = m.stripe_px
        if spindle is not None:
            m = replace(m, spindle_deg=spindle[0], about_runout=spindle[1])
        m = judged(m, i, in_use, i / 100.0)
        if i % FORM_EVERY == FORM_EVERY - 1 and in_use.runout.runout is not None:
            in_use.runout.form.roundness()  # as the service's FormWatch, every 2 s
        if i < WARM_UP:
            early += m.status is not Status.OK
            continue
        if m.status is Status.OK:
            errors.append(m.diameter_mm - case.diameter_mm)
            sigmas.append(m.uncertainty_mm)
        else:
            refused += 1
    r = in_use.runout.runout
    shape = in_use.runout.form.roundness()
    err = np.abs(np.array(errors)) * 1000.0
    true_ront = 2.0 * sum(a for _, a, _ in case.lobes) * 1000.0 if case.lobes else 0.0
    dominant = max(case.lobes, key=lambda lobe: lobe[1])[0] if case.lobes else 0
    return {
        "case": case.name, "seed": seed, "frames": frames - WARM_UP,
        "measured": len(errors), "refused": refused, "refused_in_warm_up": early,
        "mean_abs_error_um": float(err.mean()) if len(err) else None,
        "max_abs_error_um": float(err.max()) if len(err) else None,
        "max_error_over_u": float((err / (np.array(sigmas) * 1000.0)).max())
        if len(err) else None,
        "tir_true_um": 2.0 * case.eccentricity_mm * 1000.0,
        "tir_error_um": None if r is None else r.tir_mm * 1000.0
        - 2.0 * case.eccentricity_mm * 1000.0,
        "tir_uncertainty_um": None if r is None else r.tir_uncertainty_mm * 1000.0,
        "runout_frames": None if r is None else r.frames,
        "runout_reason": in_use.runout.reason or None,
        "ront_true_um": true_ront,
        "ront_error_um": shape.ront_mm * 1000.0 - true_ront if shape.ok else None,
        "lobes_true": dominant, "lobes": shape.dominant_order if shape.ok else None,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=160)
    ap.add_argument("--seeds", default=None, help="comma-separated (default: the set's)")
    ap.add_argument("--held-out", action="store_true",
                    help="the held-out cases, seeds and physics (score only at the end)")
    a = ap.parse_args()
    if a.held_out:
        cases, seeds = HELD_OUT, [901, 902]
        rig = RigConfig(sheet_sigma_mm=0.09, speckle_grain_px=1.6, speckle_contrast=0.3)
    else:
        cases, seeds, rig = TUNING, [21, 22], RigConfig()
    if a.seeds:
        seeds = [int(s) for s in a.seeds.split(",")]
    t0 = time.monotonic()
    rows = []
    for case in cases:
        for seed in seeds:
            row = run_case(case, seed, a.frames, rig)
            rows.append(row)
            print(_line(row), flush=True)
    save_report({"cases": rows, "frames": a.frames, "seeds": seeds,
                 "seconds": time.monotonic() - t0}, "turning_service", a.held_out)


def _line(r: dict) -> str:
    def f(x: float | None, fmt: str = "{:+.1f}") -> str:
        return "-" if x is None or (isinstance(x, float) and math.isnan(x)) else fmt.format(x)

    return (f"{r['case']:<36} seed {r['seed']:>3}: measured {r['measured']}/{r['frames']} "
            f"(warm-up refused {r['refused_in_warm_up']}), |err| mean "
            f"{f(r['mean_abs_error_um'], '{:.2f}')} max {f(r['max_abs_error_um'], '{:.1f}')} um, "
            f"max err/u {f(r['max_error_over_u'], '{:.1f}')}, TIR err {f(r['tir_error_um'])} um,"
            f" RONt err {f(r['ront_error_um'])} um, lobes {r['lobes']} ({r['lobes_true']})"
            + (f" [{r['runout_reason']}]" if r["tir_error_um"] is None else ""))


if __name__ == "__main__":
    main()
