"""The compensation controller: worked examples, then properties over arbitrary sequences."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from service.compensation import (
    CompensationController,
    CompensationSettings,
    ControllerState,
    Kind,
    MeasurementIn,
    State,
)

# The worked examples are the window law's (a measuring cycle's mean value), with the tuning
# it shipped with; the predictive law, the default, has its own in test_control_law.py.
LIVE = CompensationSettings(nominal_mm=30.0, shadow=False, window=3,
                            dead_time_measurements=2, dead_time_s=0.0, law="window",
                            gain=0.7, deadband_mm=0.003)


def live(settings_: CompensationSettings = LIVE, cnc_total_mm: float = 0.0,
         **kw) -> CompensationController:
    """A controller that has read the CNC's total wear offset (its baseline)."""
    c = CompensationController(settings_, **kw)
    c.observe_cnc_total(cnc_total_mm, 0.0)
    return c


def feed(ctrl, diameters, start_seq=0, t0=100.0, unc=0.001):
    out = []
    for i, d in enumerate(diameters):
        t = t0 + i
        out.append(ctrl.on_measurement(MeasurementIn(start_seq + i, t, "ok", d, unc), t))
    return out


def test_oversize_part_gives_a_negative_offset_once_the_window_is_full() -> None:
    c = live(LIVE)
    d = feed(c, [30.008, 30.008, 30.008])
    assert [x.kind for x in d] == [Kind.HELD, Kind.HELD, Kind.WRITE]
    w = d[-1]
    assert w.offset_mm == pytest.approx(-0.7 * 0.008) and w.offset_seq == 1
    assert c.state is State.PENDING
    a = c.on_write_outcome(1, True, 103.0)
    assert a.kind is Kind.APPLIED and c.cumulative_mm == pytest.approx(-0.0056)
    # dead time: the next two measurements are ignored
    d = feed(c, [30.008, 30.008], start_seq=3, t0=104)
    assert all(x.kind is Kind.HELD and "dead time" in x.reason for x in d)


@pytest.mark.parametrize(("programming", "sign", "expected"),
                         [("diameter", 1, -0.0056), ("radius", 1, -0.0028),
                          ("diameter", -1, 0.0056), ("radius", -1, 0.0028)])
def test_programming_and_sign_convention(programming, sign, expected) -> None:
    c = live(replace(LIVE, programming=programming, offset_sign=sign))
    assert feed(c, [30.008] * 3)[-1].offset_mm == pytest.approx(expected)


def test_mean_filter_weights_by_uncertainty() -> None:
    c = live(replace(LIVE, filter="mean"))
    t = 100.0
    for i, (d, u) in enumerate([(30.010, 0.001), (30.010, 0.001), (30.040, 0.010)]):
        dec = c.on_measurement(MeasurementIn(i, t + i, "ok", d, u), t + i)
    # weights 1e6, 1e6, 1e4: filtered = (0.010 * 2e6 + 0.040 * 1e4) / 2.01e6 = 0.01015
    assert dec.filtered_mm == pytest.approx(0.0101493, rel=1e-4)


def test_deadband_holds() -> None:
    c = live(LIVE)
    d = feed(c, [30.002] * 3)
    assert d[-1].kind is Kind.HELD and "deadband" in d[-1].reason


def test_step_is_clipped_and_cumulative_limit_refuses() -> None:
    s = replace(LIVE, max_step_mm=0.004, max_total_mm=0.006, tol_upper_mm=0.05,
                dead_time_measurements=0)
    c = live(s)
    w = feed(c, [30.03] * 3)[-1]
    assert w.offset_mm == pytest.approx(-0.004) and "clipped" in w.reason
    c.on_write_outcome(w.offset_seq, True, 200)
    w = feed(c, [30.03] * 3, start_seq=10, t0=300)[-1]
    assert w.offset_mm == pytest.approx(-0.002)  # up to the cumulative limit only
    c.on_write_outcome(w.offset_seq, True, 400)
    assert c.cumulative_mm == pytest.approx(-0.006)
    last = feed(c, [30.03] * 3, start_seq=20, t0=500)[-1]
    assert last.kind is Kind.LIMIT and "limit" in last.reason


@pytest.mark.parametrize("law", ["window", "predictive"])
def test_a_part_out_of_tolerance_is_flagged_and_corrected(law: str) -> None:
    """A part out is a reason to correct, so that the next one comes back (Renishaw's H,
    Siemens' _TUL/_TLL): flagged in the decision, and the offset still goes out."""
    c = live(replace(LIVE, law=law))
    writes = [x for x in feed(c, [30.03] * 3) if x.kind is Kind.WRITE]
    assert writes and writes[0].offset_mm < 0, writes
    assert "out of tolerance" in writes[0].reason and c.state is State.PENDING


def test_beyond_the_plausibility_limit_alarms_and_ends_by_itself() -> None:
    """A deviation beyond the plausibility limit (Siemens' _TDIF, Renishaw's U) writes nothing
    and alarms; the next plausible measurement ends the alarm without a person."""
    c = live(replace(LIVE, plausibility_mm=0.05))
    d = feed(c, [30.03, 30.06, 30.07])
    assert [x.kind for x in d] == [Kind.HELD, Kind.ALARM, Kind.HELD]
    assert d[1].code == "implausible" and "plausibility" in d[1].reason
    assert c.state is State.ALARM
    back = feed(c, [30.001], start_seq=5, t0=200)[0]
    assert back.kind is Kind.ACKNOWLEDGED and back.code == "plausible_again"
    assert c.state is State.ACTIVE
    feed(c, [30.07], start_seq=6, t0=300)
    assert c.acknowledge_alarm(400).kind is Kind.ACKNOWLEDGED and c.state is State.ACTIVE


def test_beyond_the_safe_area_stops_until_reset() -> None:
    c = live(LIVE)
    d = feed(c, [30.8])
    assert d[0].kind is Kind.STOPPED and c.state is State.STOPPED and "person" in d[0].reason
    assert all(x.kind is Kind.HELD for x in feed(c, [30.008] * 5, start_seq=1, t0=200))
    assert c.reset(300).kind is Kind.RESET and c.state is State.ACTIVE


@pytest.mark.parametrize(("m", "words"), [
    (MeasurementIn(1, 100, "no_stripe", None, None), "status"),
    (MeasurementIn(1, 100, "ok", math.nan, 0.001), "finite"),
    (MeasurementIn(1, 100, "ok", -30.0, 0.001), "positive"),
    (MeasurementIn(1, 100, "ok", 30.0, math.inf), "uncertainty"),
    (MeasurementIn(1, 100, "ok", 30.0, 0.05), "tolerance width"),
    (MeasurementIn(1, 50, "ok", 30.0, 0.001), "stale"),
    (MeasurementIn(1, 150, "ok", 30.0, 0.001), "future"),
])
def test_doubtful_measurements_are_refused_with_reason(m, words) -> None:
    d = live(LIVE).on_measurement(m, 100.0)
    assert d.kind is Kind.REFUSED and words in d.reason


def test_out_of_order_is_refused() -> None:
    c = live(LIVE)
    feed(c, [30.0], start_seq=5)
    d = c.on_measurement(MeasurementIn(4, 101, "ok", 30.0, 0.001), 101)
    assert d.kind is Kind.REFUSED and "out of order" in d.reason


def test_shadow_mode_proposes_and_never_writes() -> None:
    c = live(replace(LIVE, shadow=True))
    d = feed(c, [30.008] * 3)
    assert d[-1].kind is Kind.PROPOSED and d[-1].offset_mm == pytest.approx(-0.0056)
    assert c.state is State.ACTIVE and c.cumulative_mm == 0


def test_blocked_writes_are_only_proposed() -> None:
    c = live(LIVE)
    c.writes_blocked = "master check failed"
    d = feed(c, [30.008] * 3)[-1]
    assert d.kind is Kind.PROPOSED and "master check failed" in d.reason
    c.writes_blocked = ""
    assert feed(c, [30.008] * 3, start_seq=5, t0=200)[-1].kind is Kind.WRITE


def test_unknown_outcome_blocks_until_reconciled_and_is_never_resent() -> None:
    c = live(LIVE)
    w = feed(c, [30.008] * 3)[-1]
    u = c.on_write_outcome(w.offset_seq, None, 103, "PLC did not answer")
    assert u.kind is Kind.UNCERTAIN and c.state is State.UNCERTAIN
    held = feed(c, [30.008] * 6, start_seq=10, t0=104)
    assert all(x.kind is Kind.HELD for x in held)
    assert c.reset(110).kind is Kind.HELD  # no reset while unsettled
    r = c.on_write_outcome(w.offset_seq, False, 111, "settled from the CNC's registers")
    assert r.kind is Kind.NOT_APPLIED and "not be sent again" in r.reason
    assert c.cumulative_mm == 0 and c.state is State.ACTIVE
    nxt = feed(c, [30.008] * 3, start_seq=30, t0=120)[-1]
    assert nxt.kind is Kind.WRITE and nxt.offset_seq == w.offset_seq + 1


def test_state_survives_a_restart_and_a_pending_write_becomes_uncertain() -> None:
    c = live(LIVE)
    w = feed(c, [30.008] * 3)[-1]
    c.on_write_outcome(w.offset_seq, True, 103)
    kinds = [d.kind for d in feed(c, [30.008] * 6, start_seq=10, t0=110)]
    assert kinds == [Kind.HELD] * 4 + [Kind.WRITE, Kind.HELD]  # dead time 2, window 3
    saved = ControllerState(**vars(c.persisted))
    restarted = CompensationController(LIVE, saved)
    assert restarted.cumulative_mm == pytest.approx(c.cumulative_mm)
    assert restarted.state is State.UNCERTAIN  # it may or may not have reached the CNC


@pytest.mark.parametrize("change", [{"gain": 0}, {"gain": 1.5}, {"max_step_mm": 0},
                                    {"tol_upper_mm": -0.01}, {"safe_area_mm": 0.01},
                                    {"offset_sign": 2}, {"nominal_mm": -3.0},
                                    {"deadband_mm": 0.5}, {"window": 0},
                                    {"max_age_s": math.nan}])
def test_bad_settings_are_refused_naming_the_setting(change) -> None:
    with pytest.raises(ValueError) as err:
        CompensationController(replace(LIVE, **change))
    name = next(iter(change))
    assert name.split("_")[0] in str(err.value) or "finite" in str(err.value)


# ---- properties ---------------------------------------------------------------------------

diameters = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.floats(29.9, 30.1), st.floats(29.99, 30.01), st.just(-30.0), st.none())
events = st.lists(st.tuples(
    st.sampled_from(["ok", "ok", "ok", "no_stripe", "fit_failed"]),
    diameters,
    st.one_of(st.floats(0, 0.02), st.just(math.nan), st.none()),
    st.integers(-2, 3),              # seq step (out of order, repeated, forward)
    st.floats(-20.0, 3.0),           # age offset (stale, future)
    st.sampled_from([True, False, None, "skip"]),  # outcome of any write
), max_size=80)
tunings = st.builds(
    lambda shadow, step, total, prog, sign: replace(
        LIVE, shadow=shadow, max_step_mm=step, max_total_mm=max(step, total),
        programming=prog, offset_sign=sign, tol_upper_mm=0.05, tol_lower_mm=-0.05),
    st.booleans(), st.floats(0.001, 0.02), st.floats(0.001, 0.05),
    st.sampled_from(["diameter", "radius"]), st.sampled_from([1, -1]))


def run(settings_, evts):
    c = live(settings_)
    seq, now, log = 0, 1000.0, []
    for status, dia, unc, step, age, outcome in evts:
        seq += step
        now += 1.0
        m = MeasurementIn(seq, now + min(age, 0.5) if age > 0 else now + age, status, dia, unc)
        d = c.on_measurement(m, now)
        log.append((m, d, c.state, c.cumulative_mm))
        if d.kind is Kind.WRITE and outcome != "skip":
            r = c.on_write_outcome(d.offset_seq, outcome, now)
            log.append((None, r, c.state, c.cumulative_mm))
        if c.state is State.UNCERTAIN and outcome is False:
            c.on_write_outcome(c.persisted.pending_seq, False, now)
    return c, log


@settings(max_examples=300, deadline=None)
@given(tunings, events)
def test_limits_hold_for_any_sequence(s, evts) -> None:
    _, log = run(s, evts)
    for _, d, _, cum in log:
        assert abs(cum) <= s.max_total_mm + 1e-12
        if d.kind in (Kind.WRITE, Kind.PROPOSED):
            assert abs(d.offset_mm) <= s.max_step_mm + 1e-12
            assert abs(d.after_mm) <= s.max_total_mm + 1e-12


@settings(max_examples=300, deadline=None)
@given(tunings, events)
def test_writes_only_from_good_measurements_and_never_in_shadow(s, evts) -> None:
    _, log = run(s, evts)
    for m, d, _, _ in log:
        if d.kind is Kind.WRITE:
            assert not s.shadow
            assert m.status == "ok" and math.isfinite(m.diameter_mm) and m.diameter_mm > 0
            assert m.uncertainty_mm is not None and math.isfinite(m.uncertainty_mm)


@settings(max_examples=300, deadline=None)
@given(tunings, events)
def test_stops_at_the_safe_area_and_writes_nothing_after(s, evts) -> None:
    _, log = run(s, evts)
    stopped = False
    for _, d, state, _ in log:
        if d.kind is Kind.STOPPED:
            stopped = True
        if stopped:
            assert d.kind is not Kind.WRITE
            assert state is State.STOPPED
