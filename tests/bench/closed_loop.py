"""Closed loop: whole shifts of a virtual lathe (``drivers.sim.lathe``) whose parts the gauge
measures and whose wear offset the gauge's controller
(``service.compensation.CompensationController``, the real state machine) corrects, in
accelerated time.

Part to part, each part: the lathe cuts it with the CNC's total in force; the gauge measures it
``dead_parts`` parts later (its true diameter plus the gauge's noise); the controller judges
the measurement; an offset it writes is applied by the CNC at once and acts from the next part
cut. An alarm is acknowledged by the operator at once; at an insert change the operator sets
the tool's wear offset back to 0 and resets compensation, as a shop does. Continuously: one
long shaft for 8 hours, a fused diameter every 2 s of the surface under the laser, cut
``dead_s`` earlier with the offset in force then (each sample counts as a part).

Reported per case (medians over ``--seeds`` seeds): parts out of tolerance, the process mean
and standard deviation (of the true diameters, less nominal), Cpk, the share of the tolerance
band used (99.73 % of the parts), offsets written and reversed, the largest deviation in the
ten parts after an insert change; and a map of gain against dead time for a loop that
corrects every measurement (window 1, no waiting), where it oscillates, beside the
delayed integrator's limit ``g < 2 sin(pi / (2 (2d + 1)))``.

Run: ``.venv/bin/python -m tests.bench.closed_loop [--parts 500] [--seeds 5]``.
"""

from __future__ import annotations

import argparse
import itertools
import math
import statistics
from collections import deque
from dataclasses import dataclass, replace

import numpy as np

from drivers.sim.lathe import LatheConfig, VirtualLathe
from service.compensation import (
    CompensationController,
    CompensationSettings,
    ControllerState,
    Decision,
    Kind,
    MeasurementIn,
)
from tests.bench.results import save_report

NOMINAL_MM = 30.0
TOL_MM = 0.020
GAUGE_SIGMA_MM = 0.0015
"""The gauge's per-part standard uncertainty (a fused measurement of a turned part:
README's accuracy tables give 1.2-1.9 um mean |error| a frame)."""

BASE = CompensationSettings(nominal_mm=NOMINAL_MM, tol_upper_mm=TOL_MM, tol_lower_mm=-TOL_MM,
                            shadow=False, max_total_mm=1.0, max_step_mm=0.010,
                            deadband_mm=0.002, dead_time_s=0.0, max_age_s=1e9)

LAWS: dict[str, CompensationSettings] = {
    "off": replace(BASE, shadow=True),
    "window": BASE,
    "predictive": replace(BASE, law="predictive", gain=0.4, trend_gain=0.2),
}
CONTINUOUS_LAWS = {**LAWS, "predictive": replace(LAWS["predictive"], gain=0.1,
                                                 trend_gain=0.05)}
"""Continuously the gauge reports every 2 s: the predictive law's gains are per sample, so a
quarter of the part-to-part ones keeps about the same memory in wear (at 0.4 a sample it
wrote 2815 offsets in 8 h, 2041 of them reversing the one before)."""


@dataclass(frozen=True)
class Shift:
    """One shift's conditions."""

    wear_um_per_part: float = 1.0
    dead_parts: int = 1
    part_sigma_um: float = 2.0
    gauge_sigma_um: float = GAUGE_SIGMA_MM * 1000
    insert_every: int = 0          # parts between insert changes (0: none)
    chip_probability: float = 0.0
    thermal_um: float = 0.0


def carry_out(ctrl: CompensationController, d: Decision, total: float, now: float,
              steps: list[float]) -> float:
    """What the operator and the CNC do with a decision: acknowledge an alarm at once, apply
    an offset at once (the CNC's new total returned)."""
    if d.kind is Kind.ALARM:
        ctrl.acknowledge_alarm(now, "operator")
    elif d.kind is Kind.WRITE and d.offset_mm is not None and d.offset_seq is not None \
            and ctrl.check_before_write(d.offset_seq, total, now) is None:
        total += d.offset_mm
        steps.append(d.offset_mm)
        ctrl.on_write_outcome(d.offset_seq, True, now)
        ctrl.observe_cnc_total(total, now)
    return total


def run_shift(law: CompensationSettings, shift: Shift, parts: int, seed: int) -> dict:
    """One shift; its figures."""
    changes = tuple(range(shift.insert_every, parts, shift.insert_every)) \
        if shift.insert_every else ()
    lathe = VirtualLathe(LatheConfig(
        nominal_mm=NOMINAL_MM, wear_per_part_mm=shift.wear_um_per_part / 1000,
        insert_changes=changes, chip_probability=shift.chip_probability,
        thermal_mm=shift.thermal_um / 1000, thermal_tau_min=20.0,
        part_sigma_mm=shift.part_sigma_um / 1000, cycle_min=1.0), seed=seed)
    rng = np.random.default_rng(seed + 10_000)
    settings = replace(law, dead_time_measurements=shift.dead_parts)
    ctrl = CompensationController(settings, ControllerState())
    total = 0.0
    now = 0.0
    ctrl.observe_cnc_total(total, now)
    waiting: deque = deque()
    steps: list[float] = []
    seq = 0
    for k in range(parts):
        now = k * 60.0
        if k in changes:  # a new insert: the operator zeroes its wear offset and resets
            total = 0.0
            ctrl.reset(now, "operator")
            ctrl.observe_cnc_total(total, now)
        waiting.append(lathe.cut_part(total))
        if len(waiting) <= shift.dead_parts:
            continue
        part = waiting.popleft()
        seq += 1
        measured = part.diameter_mm + rng.normal(0.0, shift.gauge_sigma_um / 1000)
        total = carry_out(ctrl, ctrl.on_measurement(MeasurementIn(
            seq, now, "ok", measured, shift.gauge_sigma_um / 1000), now), total, now, steps)
    return figures(lathe, changes, steps)


@dataclass(frozen=True)
class Continuous:
    """Continuous cutting: one long shaft, the laser ``dead_s`` behind the tool (its distance
    over the feed); the gauge reports a fused diameter every ``sample_s``."""

    wear_um_per_min: float = 1.0
    dead_s: float = 10.0
    minutes: float = 480.0
    sample_s: float = 2.0
    part_sigma_um: float = 2.0     # scatter along the shaft between samples
    gauge_sigma_um: float = GAUGE_SIGMA_MM * 1000
    insert_every_min: int = 0


def run_continuous(law: CompensationSettings, c: Continuous, seed: int) -> dict:
    """One shift of continuous cutting; its figures (as ``run_shift``: each sample of the
    surface is a part)."""
    minutes = int(c.minutes)
    changes = tuple(range(c.insert_every_min, minutes, c.insert_every_min)) \
        if c.insert_every_min else ()
    lathe = VirtualLathe(LatheConfig(
        nominal_mm=NOMINAL_MM, wear_per_min_mm=c.wear_um_per_min / 1000,
        insert_changes=changes, part_sigma_mm=c.part_sigma_um / 1000), seed=seed)
    rng = np.random.default_rng(seed + 10_000)
    ctrl = CompensationController(replace(law, dead_time_measurements=0, dead_time_s=c.dead_s),
                                  ControllerState())
    total, history, steps = 0.0, [(-math.inf, 0.0)], []
    ctrl.observe_cnc_total(total, 0.0)
    for i in range(int(c.minutes * 60 / c.sample_s)):
        now = i * c.sample_s
        if changes and (now / 60) in changes:  # a new insert: zeroed and reset
            total = 0.0
            history.append((now, total))
            ctrl.reset(now, "operator")
            ctrl.observe_cnc_total(total, now)
        cut_s = now - c.dead_s  # the surface under the laser was cut then, with the
        if cut_s < 0:           # offset in force then
            continue
        in_force = next(t for s_, t in reversed(history) if s_ <= cut_s)
        part = lathe.cut_at(cut_s / 60.0, in_force)
        measured = part.diameter_mm + rng.normal(0.0, c.gauge_sigma_um / 1000)
        before = total
        total = carry_out(ctrl, ctrl.on_measurement(MeasurementIn(
            i, now, "ok", measured, c.gauge_sigma_um / 1000), now), total, now, steps)
        if total != before:
            history.append((now, total))
    return figures(lathe, [round(m * 60 / c.sample_s) for m in changes], steps)


def figures(lathe: VirtualLathe, changes: list[int] | tuple[int, ...],
            steps: list[float]) -> dict:
    """A shift's figures from the lathe's log: parts out, mean, sd, Cpk, band used, offsets
    written and reversed, the worst of the ten parts after each insert change."""
    dev = np.array([p.diameter_mm - NOMINAL_MM for p in lathe.log]) * 1000  # um
    mean, sd = float(dev.mean()), float(dev.std(ddof=1))
    tol = TOL_MM * 1000
    cpk = min(tol - mean, mean + tol) / (3 * sd) if sd > 0 else math.inf
    after = [abs(dev[c:c + 10]).max() for c in changes if c < len(dev)]
    reversals = sum(1 for a, b in itertools.pairwise(steps) if a * b < 0)
    return {"out": int((abs(dev) > tol).sum()), "mean_um": mean, "sd_um": sd, "cpk": cpk,
            "band_used": (abs(mean) + 3 * sd) / tol, "writes": len(steps),
            "reversals": reversals,
            "overshoot_um": float(max(after)) if after else None}


def median_row(law: CompensationSettings, shift: Shift | Continuous, parts: int,
               seeds: int) -> dict:
    runs = [run_continuous(law, shift, s) if isinstance(shift, Continuous)
            else run_shift(law, shift, parts, s) for s in range(seeds)]
    out: dict = {}
    for key in runs[0]:
        values = [r[key] for r in runs if r[key] is not None]
        out[key] = statistics.median(values) if values else None
    out["out_max"] = max(r["out"] for r in runs)
    return out


def oscillates(gain: float, dead_parts: int, predictive: bool = False,
               parts: int = 300) -> bool:
    """Whether a loop that corrects every measurement, with ``dead_parts`` parts between cut
    and measurement, keeps oscillating after a 20 um step (no noise, no wear): still more
    than 1 um off after ``parts`` parts. The window law corrects ``gain`` of each deviation
    as it comes (window 1, no waiting: a delayed integrator); the predictive one takes it
    into its estimate with ``gain`` and knows the dead time."""
    law = replace(BASE, window=1, gain=gain, deadband_mm=0.0,
                  dead_time_measurements=dead_parts if predictive else 0,
                  law="predictive" if predictive else "window", trend_gain=0.0,
                  max_step_mm=0.1, offset_resolution_mm=1e-6, tol_upper_mm=1.0,
                  tol_lower_mm=-1.0, safe_area_mm=5.0, max_uncertainty_fraction=1.0)
    ctrl = CompensationController(law, ControllerState())
    ctrl.observe_cnc_total(0.0, 0.0)
    total, waiting, devs = 0.0, deque(), []
    for k in range(parts):
        waiting.append(NOMINAL_MM + 0.020 + total)
        devs.append(waiting[-1] - NOMINAL_MM)
        if len(waiting) <= dead_parts:
            continue
        d = ctrl.on_measurement(MeasurementIn(k, k, "ok", waiting.popleft(), 1e-4), k)
        if d.kind is Kind.WRITE and d.offset_mm is not None and d.offset_seq is not None:
            ctrl.check_before_write(d.offset_seq, total, k)
            total += d.offset_mm
            ctrl.on_write_outcome(d.offset_seq, True, k)
            ctrl.observe_cnc_total(total, k)
    return max(abs(x) for x in devs[-20:]) > 0.001


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--parts", type=int, default=500)
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--json", default="bench-results/closed_loop.json")
    args = ap.parse_args()
    cases = {
        "wear 1 um/part, dead 1": Shift(1.0, 1),
        "wear 1 um/part, dead 3": Shift(1.0, 3),
        "wear 0.2 um/part, dead 1": Shift(0.2, 1),
        "wear 5 um/part, dead 1, inserts /40": Shift(5.0, 1, insert_every=40),
        "wear 2 um/part, dead 2, inserts /60, chips": Shift(2.0, 2, insert_every=60,
                                                            chip_probability=0.02),
        "wear 1 um/part, dead 1, warm-up 15 um": Shift(1.0, 1, thermal_um=15.0),
        "continuous 8 h: wear 1 um/min, dead 10 s": Continuous(1.0, 10.0),
        "continuous 8 h: wear 0.2 um/min, dead 1 s": Continuous(0.2, 1.0),
        "continuous 8 h: wear 5 um/min, dead 60 s, inserts /40 min": Continuous(
            5.0, 60.0, insert_every_min=40),
    }
    rows: dict = {}
    for case, shift in cases.items():
        laws = CONTINUOUS_LAWS if isinstance(shift, Continuous) else LAWS
        rows[case] = {name: median_row(law, shift, args.parts, args.seeds)
                      for name, law in laws.items()}
    gains = [0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0]
    dead = [0, 1, 2, 3]
    grid = {d: {g: oscillates(g, d) for g in gains} for d in dead}
    grid_predictive = {d: {g: oscillates(g, d, predictive=True) for g in gains} for d in dead}
    limits = {d: 2 * math.sin(math.pi / (2 * (2 * d + 1))) for d in dead}
    print(f"closed loop, part to part: {args.parts} parts a shift, {args.seeds} seeds "
          f"(medians; 'out max' the worst seed), tolerance +-{TOL_MM * 1000:.0f} um, part "
          f"scatter 2 um, gauge {GAUGE_SIGMA_MM * 1000:.1f} um\n")
    head = (f"{'case':>42} {'law':>15} {'out':>4} {'max':>4} {'mean um':>8} {'sd um':>6} "
            f"{'Cpk':>5} {'band':>5} {'writes':>6} {'rev':>4} {'after insert um':>15}")
    print(head)
    for case, by_law in rows.items():
        for name, r in by_law.items():
            ov = "-" if r["overshoot_um"] is None else f"{r['overshoot_um']:.1f}"
            print(f"{case:>42} {name:>15} {r['out']:4.0f} {r['out_max']:4d} "
                  f"{r['mean_um']:8.2f} {r['sd_um']:6.2f} {r['cpk']:5.2f} "
                  f"{r['band_used']:5.2f} {r['writes']:6.0f} {r['reversals']:4.0f} {ov:>15}")
    print("\ngain against dead time, correcting every measurement: x keeps oscillating, "
          ". settles; the delayed integrator's limit 2 sin(pi / (2 (2d + 1)))")
    print(f"{'dead parts':>10} " + " ".join(f"{g:>4.1f}" for g in gains)
          + "   limit   predictive law")
    for d in dead:
        print(f"{d:>10} " + " ".join(f"{'x' if grid[d][g] else '.':>4}" for g in gains)
              + f"   {limits[d]:.2f}    "
              + "".join("x" if grid_predictive[d][g] else "." for g in gains))
    save_report({"parts": args.parts, "seeds": args.seeds, "tolerance_um": TOL_MM * 1000,
                 "gauge_sigma_um": GAUGE_SIGMA_MM * 1000, "rows": rows,
                 "oscillation_map": {str(d): {str(g): v for g, v in grid[d].items()}
                                     for d in dead},
                 "oscillation_map_predictive": {str(d): {str(g): v for g, v in
                                                         grid_predictive[d].items()}
                                                for d in dead},
                 "limits": {str(d): v for d, v in limits.items()}}, "closed_loop",
                path=args.json)


if __name__ == "__main__":
    main()
