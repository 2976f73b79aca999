"""The dead time measured from the gauge's own offsets, against the dead time the simulated
loop has: recovered from a few steps, not from one, and never moved by one outlier."""

from __future__ import annotations

import numpy as np
import pytest

from service.compensation.dead_time import (
    CONFIRMATIONS,
    DeadTime,
    DeadTimeEstimator,
    MeasuredDeadTime,
)


def loop(dead: int, parts: int = 80, seed: int = 3, outlier_at: int | None = None,
         gain: float = 0.8, noise_um: float = 1.0, pairs: bool = False) -> DeadTimeEstimator:
    """Parts of a tool wearing 1 um a part, measured ``dead`` measurements after the cut,
    corrected now and then (every 3 to 7 measurements) by ``gain`` times what the last
    measurement showed, as a loop correcting wear does: steps of varying size. ``pairs``:
    measured two a minute, a second apart (two features of a part), not one a minute."""
    rng = np.random.default_rng(seed)
    est = DeadTimeEstimator()
    total, cut, due = 0.0, [], 4
    for k in range(parts):
        cut.append(0.001 * k + total + rng.normal(0.0, noise_um / 1000))
        if k < dead:
            continue
        y = cut[k - dead]  # the part cut ``dead`` parts ago reaches the gauge
        if outlier_at is not None and k == outlier_at:
            y += 0.015
        est.measured(y, 60.0 * (k // 2) + k % 2 if pairs else 60.0 * k)
        due -= 1
        if due == 0:
            step = -gain * y
            total += step
            est.applied(step)
            due = int(rng.integers(3, 8))
    return est


@pytest.mark.parametrize("dead", [0, 1, 2, 4, 7])
def test_the_dead_time_of_the_loop_is_recovered(dead: int) -> None:
    got = loop(dead).estimate()
    assert got is not None and got.measurements == dead, got
    assert got.seconds == pytest.approx(60.0 * dead) and got.steps >= 3


def test_one_outlier_does_not_move_the_estimate() -> None:
    """A 15 um outlier (a chip that passed every check) beside a step, for each place it can
    fall: the estimate stays the loop's dead time."""
    for at in range(20, 34):
        got = loop(3, outlier_at=at).estimate()
        assert got is not None and got.measurements == 3, (at, got)


def test_one_step_is_not_enough_and_steps_within_the_scatter_tell_nothing() -> None:
    assert loop(2, parts=10).estimate() is None  # one or two steps
    assert loop(2, gain=0.05, noise_um=3.0).estimate() is None  # lost in the scatter


def test_the_typed_dead_time_stands_unless_the_steps_tell_otherwise() -> None:
    """A prior that explains the steps within the margin is kept (a steady cadence fits a
    dead time one cadence longer almost as well); one they contradict is not."""
    est = loop(2)
    assert est.estimate(prior=2).measurements == 2
    assert est.estimate(prior=4).measurements == 2  # 2x too long: the steps say 2
    assert est.estimate(prior=1).measurements == 2  # 0.5x


def test_a_few_steps_do_not_contradict_the_typed_dead_time() -> None:
    """Two steps land on fewer than ``MIN_TELLING_AGAINST`` measurements where a typed dead
    time twice too long says they do not: it is kept. A third contradicts it."""
    got = loop(2, parts=16).estimate(prior=4)
    assert got is None or got.measurements == 4, got
    assert loop(2, parts=20).estimate(prior=4).measurements == 2


def test_measurements_at_an_unsteady_rate_do_not_refute_the_typed_dead_time() -> None:
    """Two features of a part a second apart, the next part a minute later: the dead time
    is no fixed count of measurements, and the count that fits best refutes nothing."""
    assert loop(2).estimate(prior=4).measurements == 2
    got = loop(2, pairs=True).estimate(prior=4)
    assert got is None or got.measurements == 4, got


def test_the_scatter_is_never_below_the_stated_uncertainty() -> None:
    """A few measurements' median absolute deviation can fall far below the scatter (and
    every margin with it): the stated uncertainty is the floor."""
    est = DeadTimeEstimator()
    for k in range(8):
        est.measured(0.001 * k, 60.0 * k, uncertainty_mm=0.002)
    assert est.scatter_mm() == pytest.approx(0.002)


def test_the_drift_put_in_use_is_the_wear_not_its_noise() -> None:
    """The process's move per measurement, taken when a measured dead time is put in use:
    the wear (1 um a part) within a tenth of a micrometre over 30 measurements with 1 um of
    scatter, and one 15 um outlier among them does not tilt it."""
    for outlier in (None, 60):
        dead = MeasuredDeadTime(estimator=loop(2, outlier_at=outlier))
        dead.measured_value = DeadTime(2, 120.0, 3)
        assert dead.drift_mm() == pytest.approx(0.001, abs=0.0001), outlier


@pytest.mark.parametrize(("real", "typed"), [(4, 2), (2, 4), (4, 8)])
def test_a_mis_set_dead_time_is_measured_and_put_in_use(real: int, typed: int) -> None:
    """A lathe wearing 2 um a part whose parts reach the gauge ``real`` parts after the cut,
    the dead time typed wrong by 2x: the controller measures the real one from its own
    offsets, says so once in the log, waits it from then on, and the status shows the typed,
    the measured and the one in use."""
    from collections import deque
    from dataclasses import replace

    from drivers.sim.lathe import LatheConfig, VirtualLathe
    from service.compensation import (
        CompensationController,
        CompensationSettings,
        ControllerState,
        Kind,
        MeasurementIn,
    )

    s = replace(CompensationSettings(), nominal_mm=30.0, shadow=False, max_total_mm=1.0,
                dead_time_measurements=typed, dead_time_s=0.0, max_age_s=3600.0)
    ctrl = CompensationController(s, ControllerState())
    lathe = VirtualLathe(LatheConfig(nominal_mm=30.0, wear_per_part_mm=0.002,
                                     part_sigma_mm=0.0015), seed=5)
    rng = np.random.default_rng(6)
    total, waiting, said = 0.0, deque(), []
    ctrl.observe_cnc_total(total, 0.0)
    for k in range(200):
        waiting.append(lathe.cut_part(total))
        if len(waiting) <= real:
            continue
        now = 60.0 * k
        d = ctrl.on_measurement(MeasurementIn(k, now, "ok", waiting.popleft().diameter_mm
                                              + rng.normal(0.0, 0.0015), 0.0015), now)
        if d.code == "dead_time_measured":
            said.append(d.reason)
        if d.kind is Kind.WRITE:
            assert ctrl.check_before_write(d.offset_seq, total, now) is None
            total += d.offset_mm
            ctrl.on_write_outcome(d.offset_seq, True, now)
            ctrl.observe_cnc_total(total, now)
    status = ctrl.dead.status(typed, 0.0)
    assert status["typed"] == {"measurements": typed, "seconds": 0.0}
    assert status["measured"]["measurements"] == real, status
    assert status["in_use"] == {"measurements": real, "seconds": 0.0} and status["differs"]
    assert len(said) == 1 and "now waits the measured one" in said[0], said
    assert ctrl._law.dead_measurements == real


def test_a_dead_time_typed_in_seconds_and_measured_alike_stays_in_seconds() -> None:
    """Typed as 30 s at a measurement every 2 s, measured as 15 measurements: the typed one
    stays in use (its seconds), also after an insert change starts the estimator again, and
    the measured one is what the steps must tell against (not the typed 0 measurements)."""
    from service.compensation.dead_time import DeadTime, MeasuredDeadTime

    dead = MeasuredDeadTime()
    for k in range(5):
        dead.measured(0.001, 2.0 * k, 0, 30.0)
    assert dead.typed_measurements(0, 30.0) == 15
    dead.measured_value = DeadTime(15, 30.0, 3)
    assert dead.in_use(0, 30.0) == (0, 30.0)
    dead.estimator.forget()
    assert dead.typed_measurements(0, 30.0) == 15 and dead.in_use(0, 30.0) == (0, 30.0)
    dead.measured(0.001, 20.0, 0, 30.0)
    assert dead.measured_value.measurements == 15
    assert dead.status(0, 30.0)["in_use"] == {"measurements": 0, "seconds": 30.0}


def test_a_measured_dead_time_is_used_in_seconds_where_seconds_are_typed() -> None:
    """Typed as 1.5 s at ten measurements a second: one measurement off (the rate of a busy
    host moves the typed one between 15 and 16) keeps the typed seconds; two off puts the
    measured one in use, in seconds too, so that a rate that changes later keeps its time."""
    from service.compensation.dead_time import DeadTime, MeasuredDeadTime

    for measured, in_use in ((16, (0, 1.5)), (18, (0, 1.8))):
        dead = MeasuredDeadTime()
        for k in range(5):
            dead.measured(0.001, 0.1 * k, 0, 1.5)
        dead._seen = (measured, CONFIRMATIONS - 1)
        dead.estimator.estimate = lambda prior, m=measured: DeadTime(m, m / 10, 4)
        dead.measured(0.001, 0.5, 0, 1.5)
        assert dead.measured_value.measurements == measured
        assert dead.in_use(0, 1.5) == pytest.approx(in_use), measured
