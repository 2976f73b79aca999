"""The predictive law (service/control_law.py) against analytic truth, and the controller
closing the loop around the virtual lathe (drivers/sim/lathe.py): no oscillation at any gain
up to three parts of dead time, wear followed without a steady lag."""

from __future__ import annotations

from collections import deque
from dataclasses import replace

import pytest

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
                           dead_time_s=0.0, max_age_s=1e9, offset_resolution_mm=1e-6)


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
