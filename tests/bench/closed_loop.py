"""Closed loop: whole shifts of a virtual lathe (``drivers.sim.lathe``) whose parts the gauge
measures and whose wear offset the gauge's controller
(``service.compensation.CompensationController``, the real state machine) corrects, in
accelerated time, under physics varied case by case.

Part to part, each part: the lathe cuts it with the CNC's total in force; the gauge measures it
``dead_parts`` parts later (its true diameter plus the gauge's noise: Gaussian or Student t
with 3 degrees of freedom at the same standard deviation, and outliers of 15 um that passed
every check); the controller judges the measurement; an offset it writes is applied by the
CNC at once and acts from the next part cut. Nobody acknowledges an alarm: the loop must come
back by itself. At an insert change the operator zeroes the tool's wear offset, and resets
compensation or not (``reset_at_insert``). Continuously: one long shaft for 8 hours, a fused
diameter every 2 s of the surface under the laser, cut ``dead_s`` earlier with the offset in
force then (each sample counts as a part).

The physics varied: wear shapes (break-in, linear, accelerating toward the end of an insert's
life), thermal (warm-up, a stop of an hour that cools the machine, warm-up again), gauge noise
(Gaussian, Student t, 0-3 % outliers), tolerances of +-8 to +-25 um, dead times of 0-3 parts
and 1-60 s, insert changes with and without a reset, chips.

Two laws, each as shipped: ``predictive`` (the settings' defaults) and ``window`` (window 5,
median, gain 0.7, null band 3 um: the default before). Reported per case (medians over the
seeds; ``worst`` the worst seed): parts out of tolerance, the longest run of parts out, the
process mean and standard deviation, Cpk, offsets written and reversed, the largest deviation
in the ten parts after an insert change; whether the case's wear per dead-time cycle is
within the largest step (where the loop can follow at all: the issue's criteria apply there);
and a map of gain against dead time for a loop that corrects every measurement (window 1, no
waiting), where it oscillates, beside the delayed integrator's limit.

Held out: ``--held-out`` runs other seeds (900-904) on other cases (``HELD_OUT``), written
after the tuning cases were settled and scored once at the end of a piece of work.

Run: ``.venv/bin/python -m tests.bench.closed_loop [--parts 500] [--seeds 5] [--held-out]``.
"""

from __future__ import annotations

import argparse
import itertools
import math
import statistics
from collections import deque
from dataclasses import asdict, dataclass, replace

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
GAUGE_SIGMA_UM = 1.5
"""The gauge's per-part standard uncertainty (a fused measurement of a turned part:
README's accuracy tables give 1.2-1.9 um mean |error| a frame)."""
OUTLIER_UM = 15.0
MAX_STEP_MM = 0.010

PREDICTIVE = replace(CompensationSettings(), nominal_mm=NOMINAL_MM, shadow=False,
                     max_total_mm=1.0, max_step_mm=MAX_STEP_MM, dead_time_s=0.0,
                     max_age_s=3600.0)
"""The shipped defaults, with room in the cumulative limit for a whole shift."""
LAWS: dict[str, CompensationSettings] = {
    "window": replace(PREDICTIVE, law="window", window=5, filter="median", gain=0.7,
                      deadband_mm=0.003),
    "predictive": PREDICTIVE,
}


@dataclass(frozen=True)
class Shift:
    """One shift's conditions, part to part (lengths in um)."""

    wear_um_per_part: float = 1.0
    dead_parts: int = 1
    tol_um: float = 20.0
    part_sigma_um: float = 2.0
    gauge_sigma_um: float = GAUGE_SIGMA_UM
    noise: str = "t3"                # "gauss" or "t3" (Student t, 3 degrees of freedom)
    outlier_rate: float = 0.0
    break_in_um: float = 0.0         # a new insert's first micrometres, over ~5 parts
    knee_parts: float = 0.0          # the wear rate rises past this many parts on an insert
    acceleration: float = 0.0        # ... by this many base rates every knee_parts more
    insert_every: int = 0            # parts between insert changes (0: none)
    reset_at_insert: bool = True     # the operator resets compensation (always zeroes)
    chip_probability: float = 0.0
    thermal_um: float = 0.0          # the machine's warm-up (20 min)
    stop_at: int = 0                 # before this part the machine stands ...
    stop_min: float = 0.0            # ... this long, and cools (30 min)
    typed_dead: int | None = None    # the dead time typed, measurements (None: the real one)
    every: int = 1                   # the gauge measures every this many parts
    hand_change_at: int = 0          # before this part the operator adds ...
    hand_change_um: float = 0.0      # ... this much to the wear offset at the panel

    def real_dead(self) -> int:
        """The dead time in measurements: the parts measured among those cut between an
        offset and the first part cut with it."""
        return self.dead_parts // self.every

    def cycle_wear_um(self) -> float:
        """The wear over a dead-time cycle (at the fastest rate the insert reaches)."""
        rate = self.wear_um_per_part
        if self.knee_parts and self.insert_every:
            rate *= 1 + self.acceleration * max(0.0, self.insert_every - self.knee_parts) \
                / self.knee_parts
        return rate * (self.dead_parts + 1)


@dataclass(frozen=True)
class Continuous:
    """Continuous cutting: one long shaft, the laser ``dead_s`` behind the tool; the gauge
    reports a fused diameter every ``sample_s``."""

    wear_um_per_min: float = 1.0
    dead_s: float = 10.0
    tol_um: float = 20.0
    minutes: float = 480.0
    sample_s: float = 2.0
    part_sigma_um: float = 2.0       # scatter along the shaft between samples
    gauge_sigma_um: float = GAUGE_SIGMA_UM
    noise: str = "t3"
    outlier_rate: float = 0.0
    insert_every_min: int = 0
    reset_at_insert: bool = True

    def cycle_wear_um(self) -> float:
        """The wear over a dead-time cycle."""
        return self.wear_um_per_min * (self.dead_s + self.sample_s) / 60.0


@dataclass
class Gauge:
    """The gauge's errors: noise of one standard deviation, heavy-tailed or not, and
    outliers that passed every check."""

    sigma_um: float
    noise: str
    outlier_rate: float
    rng: np.random.Generator

    def error_mm(self) -> float:
        if self.noise == "t3":  # unit variance: t3's variance is 3
            e = self.sigma_um * self.rng.standard_t(3) / math.sqrt(3.0)
        else:
            e = self.rng.normal(0.0, self.sigma_um)
        if self.rng.random() < self.outlier_rate:
            e += OUTLIER_UM * self.rng.choice((-1.0, 1.0))
        return e / 1000.0


def carry_out(ctrl: CompensationController, d: Decision, total: float, now: float,
              steps: list[float]) -> float:
    """What the CNC does with a decision: apply an offset at once (the CNC's new total
    returned). Nobody acknowledges alarms."""
    if d.kind is Kind.WRITE and d.offset_mm is not None and d.offset_seq is not None \
            and ctrl.check_before_write(d.offset_seq, total, now) is None:
        total += d.offset_mm
        steps.append(d.offset_mm)
        ctrl.on_write_outcome(d.offset_seq, True, now)
        ctrl.observe_cnc_total(total, now)
    return total


def insert_change(ctrl: CompensationController, reset: bool, now: float) -> float:
    """The operator's insert change: the wear offset zeroed, compensation reset or not."""
    if reset:
        ctrl.reset(now, "operator")
    ctrl.observe_cnc_total(0.0, now)
    return 0.0


def tolerance(law: CompensationSettings, tol_um: float) -> CompensationSettings:
    return replace(law, tol_upper_mm=tol_um / 1000, tol_lower_mm=-tol_um / 1000)


def run_shift(law: CompensationSettings, shift: Shift, parts: int, seed: int) -> dict:
    """One shift; its figures."""
    changes = tuple(range(shift.insert_every, parts, shift.insert_every)) \
        if shift.insert_every else ()
    lathe = VirtualLathe(LatheConfig(
        nominal_mm=NOMINAL_MM, wear_per_part_mm=shift.wear_um_per_part / 1000,
        break_in_mm=shift.break_in_um / 1000, wear_knee_parts=shift.knee_parts,
        wear_acceleration=shift.acceleration, insert_changes=changes,
        chip_probability=shift.chip_probability, thermal_mm=shift.thermal_um / 1000,
        thermal_tau_min=20.0, stops=((shift.stop_at, shift.stop_min),) if shift.stop_at
        else (), part_sigma_mm=shift.part_sigma_um / 1000, cycle_min=1.0), seed=seed)
    gauge = Gauge(shift.gauge_sigma_um, shift.noise, shift.outlier_rate,
                  np.random.default_rng(seed + 10_000))
    typed = shift.real_dead() if shift.typed_dead is None else shift.typed_dead
    ctrl = CompensationController(replace(tolerance(law, shift.tol_um),
                                          dead_time_measurements=typed),
                                  ControllerState())
    total, now, seq = 0.0, 0.0, 0
    ctrl.observe_cnc_total(total, now)
    waiting: deque = deque()
    steps: list[float] = []
    for k in range(parts):
        now = (k + (shift.stop_min if shift.stop_at and k >= shift.stop_at else 0.0)) * 60.0
        if k in changes:
            total = insert_change(ctrl, shift.reset_at_insert, now)
        if shift.hand_change_at and k == shift.hand_change_at:
            total += shift.hand_change_um / 1000
            ctrl.observe_cnc_total(total, now)
        waiting.append(lathe.cut_part(total))
        if len(waiting) <= shift.dead_parts:
            continue
        part = waiting.popleft()
        if (k - shift.dead_parts) % shift.every:
            continue
        seq += 1
        measured = part.diameter_mm + gauge.error_mm()
        total = carry_out(ctrl, ctrl.on_measurement(MeasurementIn(
            seq, now, "ok", measured, shift.gauge_sigma_um / 1000), now), total, now, steps)
    return figures(lathe, shift.tol_um, changes, steps)


def run_continuous(law: CompensationSettings, c: Continuous, seed: int) -> dict:
    """One shift of continuous cutting; its figures (as ``run_shift``: each sample of the
    surface is a part)."""
    minutes = int(c.minutes)
    changes = tuple(range(c.insert_every_min, minutes, c.insert_every_min)) \
        if c.insert_every_min else ()
    lathe = VirtualLathe(LatheConfig(
        nominal_mm=NOMINAL_MM, wear_per_min_mm=c.wear_um_per_min / 1000,
        insert_changes=changes, part_sigma_mm=c.part_sigma_um / 1000), seed=seed)
    gauge = Gauge(c.gauge_sigma_um, c.noise, c.outlier_rate,
                  np.random.default_rng(seed + 10_000))
    ctrl = CompensationController(replace(tolerance(law, c.tol_um), dead_time_measurements=0,
                                          dead_time_s=c.dead_s), ControllerState())
    total, history, steps = 0.0, [(-math.inf, 0.0)], []
    ctrl.observe_cnc_total(total, 0.0)
    for i in range(int(c.minutes * 60 / c.sample_s)):
        now = i * c.sample_s
        if changes and (now / 60) in changes:
            total = insert_change(ctrl, c.reset_at_insert, now)
            history.append((now, total))
        cut_s = now - c.dead_s  # the surface under the laser was cut then, with the
        if cut_s < 0:           # offset in force then
            continue
        in_force = next(t for s_, t in reversed(history) if s_ <= cut_s)
        part = lathe.cut_at(cut_s / 60.0, in_force)
        measured = part.diameter_mm + gauge.error_mm()
        before = total
        total = carry_out(ctrl, ctrl.on_measurement(MeasurementIn(
            i, now, "ok", measured, c.gauge_sigma_um / 1000), now), total, now, steps)
        if total != before:
            history.append((now, total))
    return figures(lathe, c.tol_um, [round(m * 60 / c.sample_s) for m in changes], steps)


def longest_run(out: np.ndarray) -> int:
    """The longest run of True."""
    best = run = 0
    for o in out:
        run = run + 1 if o else 0
        best = max(best, run)
    return best


def figures(lathe: VirtualLathe, tol_um: float, changes: list[int] | tuple[int, ...],
            steps: list[float]) -> dict:
    """A shift's figures from the lathe's log: parts out, the longest run out, mean, sd,
    Cpk, offsets written and reversed, the worst of the ten parts after each insert
    change."""
    dev = np.array([p.diameter_mm - NOMINAL_MM for p in lathe.log]) * 1000  # um
    mean, sd = float(dev.mean()), float(dev.std(ddof=1))
    cpk = min(tol_um - mean, mean + tol_um) / (3 * sd) if sd > 0 else math.inf
    after = [abs(dev[c:c + 10]).max() for c in changes if c < len(dev)]
    out = abs(dev) > tol_um
    return {"out": int(out.sum()), "run": longest_run(out), "mean_um": mean, "sd_um": sd,
            "cpk": cpk, "writes": len(steps),
            "reversals": sum(1 for a, b in itertools.pairwise(steps) if a * b < 0),
            "overshoot_um": float(max(after)) if after else None}


def median_row(law: CompensationSettings, case: Shift | Continuous, parts: int,
               seeds: list[int]) -> dict:
    runs = [run_continuous(law, case, s) if isinstance(case, Continuous)
            else run_shift(law, case, parts, s) for s in seeds]
    out: dict = {}
    for key in runs[0]:
        values = [r[key] for r in runs if r[key] is not None]
        out[key] = statistics.median(values) if values else None
    out["out_max"] = max(r["out"] for r in runs)
    out["run_max"] = max(r["run"] for r in runs)
    return out


CASES: dict[str, Shift | Continuous] = {
    "linear 1 um/part, dead 1, Gaussian": Shift(1.0, 1, noise="gauss"),
    "linear 1 um/part, dead 3, outliers 2 %": Shift(1.0, 3, outlier_rate=0.02),
    "linear 0.5 um/part, dead 1, +-12, gauge 2 um, outliers 3 %": Shift(
        0.5, 1, tol_um=12.0, gauge_sigma_um=2.0, outlier_rate=0.03),
    "break-in, accelerating, inserts /80 zeroed, warm-up 20 um": Shift(
        1.0, 2, break_in_um=6.0, knee_parts=50, acceleration=1.0, insert_every=80,
        reset_at_insert=False, thermal_um=20.0, outlier_rate=0.01),
    "4 um/part, dead 1, inserts /50 zeroed, warm-up 15 um": Shift(
        4.0, 1, insert_every=50, reset_at_insert=False, thermal_um=15.0),
    "1 um/part, +-12, warm-up 20 um, an hour's stop": Shift(
        1.0, 1, tol_um=12.0, thermal_um=20.0, stop_at=200, stop_min=60.0),
    "2 um/part, dead 2, inserts /60 reset, chips 2 %": Shift(
        2.0, 2, insert_every=60, chip_probability=0.02),
    "0.3 um/part, dead 0, +-8, Gaussian": Shift(0.3, 0, tol_um=8.0, noise="gauss"),
    "3 um/part, dead 2, +-25, inserts /40 reset, outliers 3 %": Shift(
        3.0, 2, tol_um=25.0, insert_every=40, outlier_rate=0.03),
    "0.2 um/part, dead 1, +-12, warm-up 10 um": Shift(0.2, 1, tol_um=12.0, thermal_um=10.0),
    "continuous: 1 um/min, dead 10 s": Continuous(1.0, 10.0),
    "continuous: 0.2 um/min, dead 1 s, outliers 2 %": Continuous(0.2, 1.0, outlier_rate=0.02),
    "continuous: 5 um/min, dead 60 s, inserts /40 min zeroed": Continuous(
        5.0, 60.0, insert_every_min=40, reset_at_insert=False),
    # The dead time typed right, 2x and 0.5x (the real one in the lathe).
    "1 um/part, dead 2, typed right": Shift(1.0, 2),
    "1 um/part, dead 2, typed 4": Shift(1.0, 2, typed_dead=4),
    "1 um/part, dead 2, typed 1": Shift(1.0, 2, typed_dead=1),
    "2 um/part, dead 4, inserts /100 zeroed, typed right": Shift(
        2.0, 4, insert_every=100, reset_at_insert=False),
    "2 um/part, dead 4, inserts /100 zeroed, typed 8": Shift(
        2.0, 4, insert_every=100, reset_at_insert=False, typed_dead=8),
    "2 um/part, dead 4, inserts /100 zeroed, typed 2": Shift(
        2.0, 4, insert_every=100, reset_at_insert=False, typed_dead=2),
    # A hand change at the panel, and the same shift without it.
    "1 um/part, dead 2, +-15, no hand change": Shift(1.0, 2, tol_um=15.0),
    "1 um/part, dead 2, +-15, +10 um at the panel": Shift(
        1.0, 2, tol_um=15.0, hand_change_at=250, hand_change_um=10.0),
    "1.5 um/part, dead 3, the gauge sees every second part": Shift(1.5, 3, every=2),
    "0.5 um/part, dead 2, +-10, gauge 2 um, outliers 3 %": Shift(
        0.5, 2, tol_um=10.0, gauge_sigma_um=2.0, outlier_rate=0.03),
    "1 um/part, dead 2, +-12, gauge 2 um, outliers 3 %, warm-up 10 um": Shift(
        1.0, 2, tol_um=12.0, gauge_sigma_um=2.0, outlier_rate=0.03, thermal_um=10.0),
}
HELD_OUT: dict[str, Shift | Continuous] = {
    "0.5 um/part, +-12, gauge 2 um, outliers 3 %, break-in 4 um, a stop": Shift(
        0.5, 1, tol_um=12.0, gauge_sigma_um=2.0, outlier_rate=0.03, break_in_um=4.0,
        thermal_um=12.0, stop_at=250, stop_min=60.0),
    "2.5 um/part, dead 2, inserts /50 zeroed, warm-up 25 um, accelerating, a stop": Shift(
        2.5, 2, insert_every=50, reset_at_insert=False, thermal_um=25.0, knee_parts=30,
        acceleration=0.5, stop_at=300, stop_min=60.0),
    "2 um/part, dead 3, +-15, inserts /70 reset, chips 3 %, outliers 1 %": Shift(
        2.0, 3, tol_um=15.0, insert_every=70, chip_probability=0.03, outlier_rate=0.01),
    "0.8 um/part, dead 2, +-10, break-in 5 um, accelerating, inserts /120": Shift(
        0.8, 2, tol_um=10.0, break_in_um=5.0, knee_parts=80, acceleration=1.0,
        insert_every=120, reset_at_insert=False),
    "continuous: 2 um/min, dead 30 s, inserts /60 min reset, outliers 1 %": Continuous(
        2.0, 30.0, insert_every_min=60, outlier_rate=0.01),
    # Written with the tuning cases above, before any tuning; scored once at the end.
    "1.5 um/part, dead 3, warm-up 15 um, typed right": Shift(1.5, 3, thermal_um=15.0),
    "1.5 um/part, dead 3, warm-up 15 um, typed 6": Shift(
        1.5, 3, thermal_um=15.0, typed_dead=6),
    "1.5 um/part, dead 6, warm-up 15 um, typed right": Shift(1.5, 6, thermal_um=15.0),
    "1.5 um/part, dead 6, warm-up 15 um, typed 3": Shift(
        1.5, 6, thermal_um=15.0, typed_dead=3),
    "0.7 um/part, dead 1, +-15, outliers 2 %, no hand change": Shift(
        0.7, 1, tol_um=15.0, outlier_rate=0.02),
    "0.7 um/part, dead 1, +-15, outliers 2 %, -10 um at the panel": Shift(
        0.7, 1, tol_um=15.0, outlier_rate=0.02, hand_change_at=320, hand_change_um=-10.0),
    "1 um/part, dead 4, every second part, inserts /90 zeroed": Shift(
        1.0, 4, every=2, insert_every=90, reset_at_insert=False),
    "0.8 um/part, dead 1, +-12, gauge 2 um, outliers 3 %, chips 1 %": Shift(
        0.8, 1, tol_um=12.0, gauge_sigma_um=2.0, outlier_rate=0.03, chip_probability=0.01),
}
TUNING_SEEDS = [0, 1, 2, 3, 4]
HELD_OUT_SEEDS = [900, 901, 902, 903, 904]


def oscillates(gain: float, dead_parts: int, predictive: bool = False,
               parts: int = 300) -> bool:
    """Whether a loop that corrects every measurement, with ``dead_parts`` parts between cut
    and measurement, keeps oscillating after a 20 um step (no noise, no wear): still more
    than 1 um off after ``parts`` parts. The window law corrects ``gain`` of each deviation
    as it comes (window 1, no waiting: a delayed integrator); the predictive one takes it
    into its estimate with ``gain`` and knows the dead time."""
    law = replace(PREDICTIVE, window=1, gain=gain, deadband_mm=0.0,
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


def verdict(case: Shift | Continuous, by_law: dict) -> dict:
    """The issue's criteria for one case: within the largest step, the longest run out no
    longer than the dead time plus 2 parts (samples), Cpk, reversals against the window."""
    p, w = by_law["predictive"], by_law["window"]
    dead = case.dead_parts if isinstance(case, Shift) else math.ceil(
        case.dead_s / case.sample_s)
    return {"within_step": case.cycle_wear_um() <= MAX_STEP_MM * 1000,
            "run_ok": p["run_max"] <= dead + 2, "dead": dead,
            "reversals_ok": p["reversals"] <= w["reversals"]}


MIS_SET = ", typed "
HAND = " at the panel"


def against_sibling(name: str, rows: dict) -> dict:
    """The issue's criteria against the same case done right: a dead time mis-set keeps the
    predictive law's Cpk within 10 % of the case typed right and its longest run out within
    the real dead time + 3; a hand change leaves no part out where none was without it; a
    +-12 um case with a 2 um gauge and outliers holds a median Cpk of 1.33."""
    p = rows[name]["laws"]["predictive"]
    case = rows[name]["case"]
    out: dict = {}
    if MIS_SET in name and not name.endswith("typed right"):
        right = rows.get(name.rsplit(MIS_SET, 1)[0] + MIS_SET + "right")
        if right:
            ratio = p["cpk"] / right["laws"]["predictive"]["cpk"]
            out["cpk_ratio"] = round(ratio, 3)
            out["mis_set_ok"] = ratio >= 0.9 and p["run_max"] <= case["dead_parts"] + 3
    if name.endswith(HAND):
        without = rows.get(name.rsplit(", ", 1)[0] + ", no hand change")
        if without:
            out["hand_ok"] = without["laws"]["predictive"]["out_max"] > 0 or p["out_max"] == 0
    if case.get("tol_um") == 12.0 and case.get("gauge_sigma_um") == 2.0 \
            and case.get("outlier_rate") == 0.03:
        out["tight_ok"] = p["cpk"] >= 1.33
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--parts", type=int, default=500)
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--held-out", action="store_true",
                    help="the held-out cases and seeds (score once, at the end)")
    ap.add_argument("--json", default=None)
    ap.add_argument("--only", default="", help="the cases whose name has this in it")
    args = ap.parse_args()
    cases = {k: v for k, v in (HELD_OUT if args.held_out else CASES).items()
             if args.only in k}
    seeds = (HELD_OUT_SEEDS if args.held_out else TUNING_SEEDS)[:args.seeds]
    rows: dict = {}
    for name, case in cases.items():
        by_law = {law: median_row(settings, case, args.parts, seeds)
                  for law, settings in LAWS.items()}
        rows[name] = {"case": {"kind": type(case).__name__, **asdict(case)}, "laws": by_law,
                      "verdict": verdict(case, by_law)}
    for name, row in rows.items():
        row["verdict"].update(against_sibling(name, rows))
    print(f"closed loop, {'HELD-OUT' if args.held_out else 'tuning'} cases: {args.parts} "
          f"parts a shift, seeds {seeds} (medians; 'worst' the worst seed)\n")
    print(f"{'case':>66} {'law':>10} {'out':>4} {'run':>4} {'worst':>5} {'mean':>6} "
          f"{'sd':>5} {'Cpk':>5} {'writes':>6} {'rev':>4} {'after insert':>12}")
    for name, row in rows.items():
        for law, r in row["laws"].items():
            ov = "-" if r["overshoot_um"] is None else f"{r['overshoot_um']:.1f}"
            print(f"{name[:66]:>66} {law:>10} {r['out']:4.0f} {r['run']:4.0f} "
                  f"{r['run_max']:5d} {r['mean_um']:6.2f} {r['sd_um']:5.2f} {r['cpk']:5.2f} "
                  f"{r['writes']:6.0f} {r['reversals']:4.0f} {ov:>12}")
        v = row["verdict"]
        print(f"{'':>66} {'verdict':>10} within step {v['within_step']}, longest run <= "
              f"{v['dead']} + 2: {v['run_ok']}, reversals <= window's: {v['reversals_ok']}"
              + "".join(f", {k}: {v[k]}" for k in ("cpk_ratio", "mis_set_ok", "hand_ok",
                                                   "tight_ok") if k in v))
    report: dict = {"parts": args.parts, "seeds": seeds, "held_out": args.held_out,
                    "gauge_sigma_um": GAUGE_SIGMA_UM, "outlier_um": OUTLIER_UM,
                    "max_step_um": MAX_STEP_MM * 1000, "rows": rows}
    if not args.held_out:
        gains = [0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0]
        dead = [0, 1, 2, 3]
        report["oscillation_map"] = {str(d): {str(g): oscillates(g, d) for g in gains}
                                     for d in dead}
        report["oscillation_map_predictive"] = {
            str(d): {str(g): oscillates(g, d, predictive=True) for g in gains} for d in dead}
        report["limits"] = {str(d): 2 * math.sin(math.pi / (2 * (2 * d + 1))) for d in dead}
    save_report(report, "closed_loop_held_out" if args.held_out else "closed_loop",
                path=args.json or ("bench-results/closed_loop_held_out.json" if args.held_out
                                   else "bench-results/closed_loop.json"))


if __name__ == "__main__":
    main()
