"""The predictive law (service/compensation/laws.py) against analytic truth, and the controller
closing the loop around the virtual lathe (drivers/sim/lathe.py): no oscillation at any gain
up to three parts of dead time, wear followed without a steady lag."""

from __future__ import annotations

import math
from collections import deque
from dataclasses import replace

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.sim.lathe import LatheConfig, VirtualLathe
from service.compensation import (
    CompensationController,
    CompensationSettings,
    ControllerState,
    Kind,
    MeasurementIn,
)
from service.compensation.laws import Predictor

LAW = CompensationSettings(nominal_mm=30.0, tol_upper_mm=0.02, tol_lower_mm=-0.02,
                           shadow=False, law="predictive", gain=0.4, trend_gain=0.2,
                           deadband_mm=0.0, max_step_mm=0.05, max_total_mm=1.0,
                           dead_time_s=0.0, max_age_s=3600.0, offset_resolution_mm=1e-6)


def test_holt_follows_a_straight_line_exactly() -> None:
    """Noise-free linear wear: the forecast h steps ahead is the line's value there (the
    mean-value band wide: nothing is doubted)."""
    p = Predictor(gain=0.4, trend_gain=0.2, horizon=3, band_mm=0.05)
    for k in range(200):
        forecast = p.observe(0.005 + 0.001 * k, 0.0, float(k))
    assert forecast == pytest.approx(0.005 + 0.001 * (199 + 3), abs=1e-9)


def test_offsets_in_flight_do_not_move_the_estimate() -> None:
    """A constant process; an offset applied shows two measurements later. The deviations
    measured meanwhile, before and after it shows, all say the same process."""
    p = Predictor(gain=0.5, trend_gain=0.0, horizon=3, band_mm=0.05)
    for k in range(20):
        p.observe(0.010, 0.0, float(k))
    p.applied(-0.006, after_measurements=2, visible_at_s=0.0)
    assert p.in_flight_mm() == pytest.approx(-0.006)
    for k, dev in enumerate((0.010, 0.010, 0.004, 0.004)):  # cut before, before, after
        assert p.observe(dev, -0.006, 20.0 + k) == pytest.approx(0.010, abs=1e-12)
    assert p.in_flight_mm() == 0.0


def run_loop(settings: CompensationSettings, dead: int, parts: int, wear_um: float,
             step_um: float = 0.0, seed: int = 0) -> list[float]:
    """Deviations (um) of the parts a virtual lathe cuts under the controller."""
    lathe = VirtualLathe(LatheConfig(wear_per_part_mm=wear_um / 1000, part_sigma_mm=0.0),
                         seed=seed)
    ctrl = CompensationController(replace(settings, dead_time_measurements=dead),
                                  ControllerState())
    ctrl.observe_cnc_total(0.0, 0.0)
    # The step is the process's (a setting-up error): the CNC's total starts at 0.
    total, waiting = 0.0, deque()
    for k in range(parts):
        waiting.append(lathe.cut_part(total + step_um / 1000))
        if len(waiting) <= dead:
            continue
        part = waiting.popleft()
        d = ctrl.on_measurement(MeasurementIn(k, k, "ok", part.diameter_mm, 1e-4), k)
        if d.kind is Kind.ALARM:
            ctrl.acknowledge_alarm(k)
        if d.kind is Kind.WRITE:
            assert ctrl.check_before_write(d.offset_seq, total, k) is None
            total += d.offset_mm
            ctrl.on_write_outcome(d.offset_seq, True, k)
            ctrl.observe_cnc_total(total, k)
    return [(p.diameter_mm - 30.0) * 1000 for p in lathe.log]


@pytest.mark.parametrize("dead", [0, 1, 2, 3])
@pytest.mark.parametrize("gain", [0.3, 0.7, 1.0])
def test_a_step_settles_at_any_gain_and_dead_time(gain: float, dead: int) -> None:
    """A part 15 um oversize from the start: where correcting a share of each deviation
    oscillates (gain 1.0 at one part of dead time, 0.7 at two), the predictive law settles."""
    devs = run_loop(replace(LAW, gain=gain, trend_gain=0.0), dead, 80, 0.0, step_um=15.0)
    assert max(abs(x) for x in devs[-20:]) < 0.05, devs
    assert max(devs) <= 15.0 + 1e-9 and min(devs) > -5.0  # no overshoot beyond the step


@pytest.mark.parametrize("dead", [1, 3])
def test_wear_is_followed_without_a_steady_lag(dead: int) -> None:
    """1 um per part (out of +-20 um within 20 parts uncompensated): the double EWMA keeps
    the parts at nominal, a single one lags by about the wear over its memory."""
    double = run_loop(LAW, dead, 200, 1.0)
    single = run_loop(replace(LAW, trend_gain=0.0), dead, 200, 1.0)
    assert max(abs(x) for x in double[-50:]) < 0.2
    assert sum(single[-50:]) / 50 > 1.0  # the lag a single EWMA leaves


def test_the_window_law_is_still_there_for_comparison() -> None:
    window = replace(LAW, law="window", window=5, gain=0.7, deadband_mm=0.002)
    devs = run_loop(window, 1, 200, 1.0)
    assert max(abs(x) for x in devs[-50:]) < 20.0
    assert sum(devs[-50:]) / 50 > 5.0  # it waits out dead time and window: parts run large


# ---- the loop that comes back by itself ---------------------------------------------------

DEFAULTS = replace(CompensationSettings(), nominal_mm=30.0, shadow=False, max_total_mm=1.0,
                   dead_time_s=0.0, max_age_s=3600.0)


class Loop:
    """The controller around a lathe whose process the test writes part by part: each part
    cut is ``process(k) + total``, measured ``dead`` parts later; offsets applied at once."""

    def __init__(self, settings: CompensationSettings, dead: int) -> None:
        self.ctrl = CompensationController(replace(settings, dead_time_measurements=dead),
                                           ControllerState())
        self.ctrl.observe_cnc_total(0.0, 0.0)
        self.dead, self.total, self.k = dead, 0.0, 0
        self.waiting: deque = deque()
        self.cut: list[float] = []       # deviations cut, um
        self.decisions: list = []        # (k, decision)

    def part(self, process_mm: float, measured_error_mm: float = 0.0,
             now: float | None = None) -> None:
        now = float(self.k) if now is None else now
        self.cut.append((process_mm + self.total) * 1000)
        self.waiting.append(30.0 + process_mm + self.total)
        self.k += 1
        if len(self.waiting) <= self.dead:
            return
        d = self.ctrl.on_measurement(MeasurementIn(
            self.k, now, "ok", self.waiting.popleft() + measured_error_mm, 0.0015), now)
        self.decisions.append((self.k, d))
        if d.kind is Kind.WRITE:
            assert self.ctrl.check_before_write(d.offset_seq, self.total, now) is None
            self.total += d.offset_mm
            self.ctrl.on_write_outcome(d.offset_seq, True, now)
            self.ctrl.observe_cnc_total(self.total, now)

    def writes_from(self, k: int) -> list:
        return [d for i, d in self.decisions if i >= k and d.kind is Kind.WRITE]


@settings(max_examples=200, deadline=None)
@given(level_um=st.floats(-15.0, 15.0), dead=st.integers(0, 3),
       tol_um=st.floats(8.0, 25.0), at=st.integers(0, 20), fraction=st.floats(-1.0, 1.0),
       gain=st.floats(0.1, 0.6), trend_gain=st.floats(0.0, 0.3))
def test_no_single_outlier_writes_an_offset(level_um, dead, tol_um, at, fraction, gain,
                                            trend_gain) -> None:
    """A settled process (noise-free, so that nothing else would write) and one measurement
    off by anything up to the plausibility limit: no offset, then or after."""
    s = replace(DEFAULTS, tol_upper_mm=tol_um / 1000, tol_lower_mm=-tol_um / 1000,
                gain=gain, trend_gain=trend_gain)
    loop = Loop(s, dead)
    for _ in range(60):
        loop.part(level_um / 1000)
    assert abs(loop.cut[-1]) <= max(s.deadband_mm * 1000, 2.5), loop.cut  # settled
    outlier = fraction * s.plausibility()
    start = loop.k
    for i in range(30):
        loop.part(level_um / 1000, outlier if i == at else 0.0)
    assert not loop.writes_from(start + 1), (outlier, loop.writes_from(start + 1))


@pytest.mark.parametrize("dead", [0, 1, 2, 3])
@pytest.mark.parametrize("step_um", [-12.0, 9.0, 25.0])
def test_a_real_step_is_followed_within_the_dead_time_and_two(dead: int,
                                                              step_um: float) -> None:
    """A chipped or a new insert: the first measurement of it is set aside, the second
    confirms it and the offset goes out, so the step is corrected from the part cut after
    the dead time plus two measurements on (and nothing overshoots)."""
    loop = Loop(DEFAULTS, dead)
    for _ in range(40):
        loop.part(0.004)
    n = loop.k
    for _ in range(20):
        loop.part(0.004 + step_um / 1000)
    writes = loop.writes_from(n)
    # Part j is measurement j + dead + 1: the step's second part measured is n + dead + 2.
    assert writes and writes[0].measurement_seq <= n + dead + 2, writes
    back = loop.cut[n + dead + 2 + math.ceil(abs(step_um) / 10) - 1:]  # max step 10 um
    assert max(abs(x) for x in back) < 3.0, loop.cut[n:]


def test_an_insert_change_zeroed_at_the_cnc_is_judged_with_and_not_corrected_back() -> None:
    """The operator zeroes the wear offset at an insert change (no reset): the gauge sees the
    CNC's total move without its offset, logs it, corrects nothing before the parts cut with
    it are measured, and the new insert's parts come back without an overshoot."""
    loop = Loop(DEFAULTS, 2)
    wear = [0.001 * k for k in range(60)]
    for w in wear:
        loop.part(0.010 + w)  # 10 um of growth the offset also carries
    total_before = loop.total
    assert total_before < -0.05
    loop.total = 0.0  # the new insert, the wear offset zeroed by hand
    change = loop.ctrl.observe_cnc_total(0.0, float(loop.k))
    assert change is not None and change.kind is Kind.BASELINE
    assert change.code == "cnc_total_changed" and "insert change" in change.reason
    n = loop.k
    for k in range(30):
        loop.part(0.010 + 0.001 * k)
    new = loop.cut[n:]
    # The growth lost with the offset is out for at most the dead time plus two parts; the
    # gauge never pulls the tool back toward the old insert's offset.
    assert sum(abs(x) > 20.0 for x in new) <= 2 + 2, new
    assert min(new) > -20.0 and max(abs(x) for x in new[6:]) < 5.0, new
    assert all(d.offset_mm > -0.02 for d in loop.writes_from(n)), loop.writes_from(n)


@pytest.mark.parametrize("hand_um", [10.0, -10.0])
@pytest.mark.parametrize("dead", [1, 3])
def test_a_hand_change_at_the_panel_is_a_known_step(hand_um: float, dead: int) -> None:
    """Mid-run, the operator adds 10 um to the wear offset at the panel: a change the gauge
    did not make, which is not a setting back. It is logged as a hand change, taken as a
    known step (the process estimate does not jump when it lands) and corrected back at the
    next measurement: one part carries it, none after."""
    loop = Loop(DEFAULTS, dead)
    for k in range(60):
        loop.part(0.001 * k)
    assert loop.total < -0.040
    loop.total += hand_um / 1000
    change = loop.ctrl.observe_cnc_total(loop.total, float(loop.k))
    assert change is not None and change.code == "hand_change", change
    assert "hand change" in change.reason
    n = loop.k
    for k in range(60, 90):
        loop.part(0.001 * k)
    after = loop.cut[n:]
    assert abs(after[0]) > 7.0, after       # the part cut with the hand change
    assert max(abs(x) for x in after[1:]) < 4.0, after  # the next one is back
    assert not any("step" in d.reason for _, d in loop.decisions[n:]), loop.decisions[n:]


def test_a_second_insert_change_is_corrected_before_it_is_seen() -> None:
    """After one insert change the gauge knows where a new insert's parts stand; at the next
    one the machine's growth the zeroed offset loses is corrected at the first measurement,
    before the new insert's parts are measured."""
    loop = Loop(DEFAULTS, 2)
    for change in range(3):
        if change:
            loop.total = 0.0
            loop.ctrl.observe_cnc_total(0.0, float(loop.k))
        n = loop.k
        for k in range(50):
            loop.part(0.015 + 0.001 * k)
    third = loop.cut[n:]
    assert sum(abs(x) > 20.0 for x in third) == 0, third
    assert max(third[:4]) > 12.0  # the lost growth shows on the parts cut before the offset


def test_after_a_stop_the_first_part_sets_the_process() -> None:
    """An hour's stop cooled the machine by 15 um: the gap between measurements says so,
    and the first part after it moves the estimate without waiting for a second."""
    loop = Loop(DEFAULTS, 1)
    for k in range(40):
        loop.part(0.010, now=60.0 * k)
    n = loop.k
    for k in range(10):
        loop.part(-0.005, now=60.0 * (40 + k) + 3600.0)
    writes = loop.writes_from(n)
    # Part j is measurement j + 2: the first part cut after the stop is measurement n + 2.
    assert writes and writes[0].measurement_seq == n + 2 and writes[0].offset_mm > 0, writes


def test_a_change_at_the_cnc_seen_just_before_a_write_drops_the_write_and_says_so() -> None:
    """The wear offset zeroed between an offset's decision and its write: the fresh reading
    before the write shows it; that offset (decided for the old total) is not written, and
    the change is logged as one at the CNC."""
    c = CompensationController(replace(DEFAULTS, dead_time_measurements=0), ControllerState())
    c.observe_cnc_total(-0.050, 0.0)
    d = [c.on_measurement(MeasurementIn(k, float(k), "ok", 30.010, 0.0015), float(k))
         for k in (1, 2)][-1]
    assert d.kind is Kind.WRITE
    veto = c.check_before_write(d.offset_seq, 0.0, 3.0)
    assert veto is not None and veto.code == "cnc_total_changed", veto
    assert "insert change" in veto.reason and veto.measurement_seq == 2
    assert c.state.value == "active" and c.persisted.cnc_total_mm == 0.0


def test_the_gains_follow_the_process() -> None:
    """The settings' gains are the most: taken whole where the process moves by two of its
    scatters or more over a dead-time cycle, 0.4 of them where it stands still against its
    scatter, and whole until two spans of values tell."""
    import numpy as np

    from service.compensation.laws import MIN_GAIN_SHARE, MOVE_SPAN

    rng = np.random.default_rng(4)
    still = Predictor(gain=0.3, trend_gain=0.15, horizon=2)
    fast = Predictor(gain=0.3, trend_gain=0.15, horizon=2)
    for k in range(120):
        still.observe(float(rng.normal(0.0, 0.003)), 0.0, float(k), 0.003)
        fast.observe(0.004 * k + float(rng.normal(0.0, 0.001)), 0.0, float(k), 0.001)
        if k < MOVE_SPAN:
            assert still.gains() == (0.3, 0.15)
    assert still.gains() == pytest.approx((0.3 * MIN_GAIN_SHARE, 0.15 * MIN_GAIN_SHARE))
    assert fast.gains() == (0.3, 0.15)
