"""The CNC loop as a whole: the offset channel with its controller against a CNC model that
applies late, clears requests it will not apply, and survives the gauge's restarts.

Properties over any interleaving of measurements, resets (a technician's over the API, the
CNC's from its command register with the setting off), restarts, late and missing
acknowledgements and writes lost on the way: the CNC's total never leaves
``max_total_mm`` around where it stood when compensation was enabled or last reset by a
person; no offset is sent or applied twice; once everything is settled the log's applied
offsets add up to the CNC's total.
"""

from __future__ import annotations

import asyncio
import json
from dataclasses import asdict, dataclass, field, replace

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.plc.client import Outcome, WriteResult
from service.compensation import (
    CncReading,
    CompensationController,
    CompensationSettings,
    ControllerState,
    Decision,
    Kind,
    MeasurementIn,
    State,
)
from service.runtime.offset_channel import OffsetChannel

# The window law with the tuning these handshakes were written with (the figures below are
# its corrections); the handshakes do not depend on the law.
LIVE = CompensationSettings(nominal_mm=30.0, shadow=False, law="window", gain=0.7,
                            window=2, deadband_mm=0.001,
                            dead_time_measurements=0, dead_time_s=0.0, max_step_mm=0.01,
                            max_total_mm=0.03, tol_upper_mm=0.05, tol_lower_mm=-0.05)


@dataclass
class FakeCnc:
    """A CNC's offset registers. Each write is applied after ``delays`` ticks (0: at once,
    acknowledged within the gauge's timeout), cleared instead (``"clear"``: a request the CNC
    will not apply), or lost before it reaches the CNC (``"lost"``)."""

    total_mm: float = 0.0
    ack_seq: int = 0
    request_seq: int = 0
    plans: list = field(default_factory=list)   # what the next writes meet
    due: list = field(default_factory=list)     # [ticks left, seq, value]
    sent: list = field(default_factory=list)    # sequences written
    applied: list = field(default_factory=list)  # (seq, value)

    async def write_offset(self, offset_mm: float, seq: int) -> WriteResult:
        self.sent.append(seq)
        plan = self.plans.pop(0) if self.plans else 0
        if plan == "lost":
            return WriteResult(Outcome.UNKNOWN, seq, 0, "no answer to the write", 0.0)
        self.request_seq = seq
        if plan == 0:
            self._apply(seq, offset_mm)
            return WriteResult(Outcome.APPLIED, seq, 0, "acknowledged", 0.0)
        self.due.append([plan, seq, offset_mm])
        return WriteResult(Outcome.UNKNOWN, seq, 0, "no acknowledgement in time", 0.0)

    async def read_cnc(self) -> CncReading:
        return CncReading(self.ack_seq, self.request_seq, self.total_mm)

    def _apply(self, seq: int, value: float) -> None:
        assert seq not in [s for s, _ in self.applied], f"offset {seq} applied twice"
        self.total_mm += value
        self.ack_seq = seq
        self.applied.append((seq, value))

    def tick(self) -> None:
        for item in list(self.due):
            if item[0] == "clear":
                self.due.remove(item)
                if self.request_seq == item[1]:
                    self.request_seq = 0
                continue
            item[0] -= 1
            if item[0] <= 0:
                self.due.remove(item)
                if self.request_seq == item[1]:
                    self._apply(item[1], item[2])


class Loop:
    """The gauge's side: a channel that can be restarted from its persisted state."""

    def __init__(self, cnc: FakeCnc, s: CompensationSettings) -> None:
        self.cnc, self.settings, self.now = cnc, s, 1000.0
        self.decisions: list[Decision] = []
        self.persisted = ControllerState()
        self.seq = 0
        self.channel = self._channel()

    def _channel(self) -> OffsetChannel:
        state = ControllerState(**json.loads(json.dumps(asdict(self.persisted))))
        c = CompensationController(self.settings, state)
        self.persisted = c.persisted
        return OffsetChannel(c, self.cnc, None, on_decision=self.decisions.append,
                             clock=lambda: self.now)

    def restart(self) -> None:
        self.settings = self.channel.controller.settings
        self.channel = self._channel()

    async def measure(self, diameter_mm: float) -> None:
        self.seq += 1
        self.now += 1.0
        await self.channel.on_measurement(MeasurementIn(self.seq, self.now, "ok", diameter_mm,
                                                        0.001))

    async def settler_tick(self) -> None:
        """What ``EntryChannels.run_settlers`` does once."""
        self.now += 1.0
        if self.channel.controller.state is State.UNCERTAIN:
            await self.channel.settle()
        else:
            await self.channel.refresh()


events = st.lists(st.one_of(
    st.tuples(st.just("measure"), st.integers(1, 8)),   # a burst of measurements
    st.tuples(st.just("tick"), st.none()),
    st.tuples(st.just("reset_api"), st.none()),
    st.tuples(st.just("reset_modbus"), st.none()),
    st.tuples(st.just("restart"), st.none()),
    st.tuples(st.just("shadow"), st.booleans()),
), min_size=10, max_size=120)
deviations = st.one_of(st.sampled_from([-0.02, -0.008, 0.008, 0.02]), st.floats(-0.04, 0.04))
plans = st.lists(st.one_of(st.just(0), st.integers(1, 6), st.just("clear"), st.just("lost")),
                 max_size=40)


def run_loop(evts, write_plans, start_total_mm: float = 0.0, deviation_mm: float = 0.008,
             settings_: CompensationSettings = LIVE):
    """Run the events; a burst of measurements reads nominal + ``deviation_mm`` (the part
    keeps its size: a tool that wears while nothing is corrected)."""
    cnc = FakeCnc(total_mm=start_total_mm, plans=list(write_plans))
    cnc_ref = [start_total_mm]  # where the CNC stood at enabling or a person's last reset
    loop = Loop(cnc, settings_)
    excursions = []

    async def go() -> None:
        await loop.settler_tick()  # the service reads the CNC first
        for what, arg in evts:
            c = loop.channel.controller
            if what == "measure":
                for _ in range(arg):
                    await loop.measure(30.0 + deviation_mm)
            elif what == "tick":
                cnc.tick()
                await loop.settler_tick()
            elif what == "reset_api":
                d = await loop.channel.command("reset", who="api:technician")
                if d.kind is Kind.RESET:
                    cnc_ref[0] = cnc.total_mm
            elif what == "reset_modbus":  # modbus.reset_command off: refused, logged
                await loop.channel.refuse_reset("modbus", "resets from the CNC are off")
            elif what == "restart":
                loop.restart()
                await loop.settler_tick()
            elif what == "shadow":
                was = c.settings.shadow
                try:
                    await loop.channel.update_settings(replace(c.settings, shadow=arg),
                                                       "api:technician")
                except ValueError:
                    pass
                else:
                    if was and not arg:
                        cnc_ref[0] = cnc.total_mm
            excursions.append(cnc.total_mm - cnc_ref[0])
        # Settle everything: the CNC finishes what it will do, the gauge reads it.
        for _ in range(10):
            cnc.tick()
            await loop.settler_tick()

    asyncio.run(go())
    return cnc, loop, excursions


@settings(max_examples=250, deadline=None)
@given(events, plans, st.floats(-0.2, 0.2), deviations)
def test_the_cnc_total_stays_within_the_limit_of_its_reference(evts, write_plans,
                                                                start_total, dev) -> None:
    _, _, excursions = run_loop(evts, write_plans, start_total, dev)
    for x in excursions:
        assert abs(x) <= LIVE.max_total_mm + 1e-9, excursions


@settings(max_examples=250, deadline=None)
@given(events, plans, deviations)
def test_no_offset_twice_and_the_log_adds_up_to_the_cnc(evts, write_plans, dev) -> None:
    cnc, loop, _ = run_loop(evts, write_plans, 0.0, dev)
    assert len(cnc.sent) == len(set(cnc.sent)), cnc.sent   # each sent once
    applied_log = [d for d in loop.decisions if d.kind is Kind.APPLIED]
    assert sorted(d.offset_seq for d in applied_log) == sorted(s for s, _ in cnc.applied)
    assert sum(d.offset_mm for d in applied_log) == pytest.approx(cnc.total_mm, abs=1e-9)
    assert loop.channel.controller.state is not State.UNCERTAIN  # all settled in the end
    for d in loop.decisions:  # in the CNC's resolution (0.1 um), so the books agree exactly
        if d.kind is Kind.WRITE:
            units = d.offset_mm / LIVE.offset_resolution_mm
            assert abs(units - round(units)) < 1e-6, d


PREDICTIVE = replace(LIVE, law="predictive", gain=0.3, trend_gain=0.15)


@settings(max_examples=250, deadline=None)
@given(events, plans, st.floats(-0.2, 0.2), deviations)
def test_the_default_law_keeps_the_same_exchange(evts, write_plans, start_total,
                                                 dev) -> None:
    """The same sequences under the predictive law (it writes more often): the limit on the
    CNC's total, each offset once, the log adding up to the CNC."""
    cnc, loop, excursions = run_loop(evts, write_plans, start_total, dev, PREDICTIVE)
    assert all(abs(x) <= LIVE.max_total_mm + 1e-9 for x in excursions), excursions
    assert len(cnc.sent) == len(set(cnc.sent)), cnc.sent
    applied_log = [d for d in loop.decisions if d.kind is Kind.APPLIED]
    assert sorted(d.offset_seq for d in applied_log) == sorted(s for s, _ in cnc.applied)
    assert sum(d.offset_mm for d in applied_log) + start_total == pytest.approx(
        cnc.total_mm, abs=1e-9)


def test_a_late_acknowledgement_is_applied_not_lost() -> None:
    """Acknowledged after the timeout: uncertain, nothing else sent, then applied."""
    cnc, loop, _ = run_loop([("measure", 2), ("measure", 3)] + [("tick", None)] * 2, [3])
    kinds = [d.kind for d in loop.decisions if d.kind not in (Kind.HELD, Kind.BASELINE)]
    assert kinds[:3] == [Kind.WRITE, Kind.UNCERTAIN, Kind.APPLIED], kinds
    assert cnc.sent == [1] and cnc.total_mm == pytest.approx(-0.0056)
    assert loop.channel.controller.cumulative_mm == pytest.approx(cnc.total_mm)


def test_a_request_the_cnc_clears_is_not_applied_and_never_resent() -> None:
    cnc, loop, _ = run_loop([("measure", 2)] + [("tick", None)] * 3, ["clear"])
    d = [d for d in loop.decisions if d.kind is Kind.NOT_APPLIED]
    assert len(d) == 1 and "cleared by the CNC" in d[0].reason
    assert cnc.sent == [1] and cnc.total_mm == 0


def test_a_cnc_that_never_answers_holds_everything() -> None:
    """Acknowledgement never comes and the request stays: uncertain for as long as that
    lasts, nothing else sent, not even after restarts."""
    cnc = FakeCnc(plans=[10_000])
    loop = Loop(cnc, LIVE)

    async def go() -> None:
        await loop.settler_tick()
        for i in range(60):
            await loop.measure(30.008)
            if i % 20 == 19:
                loop.restart()
            await loop.settler_tick()

    asyncio.run(go())
    assert cnc.sent == [1]
    assert loop.channel.controller.state is State.UNCERTAIN


def test_resets_cannot_walk_the_tool_beyond_the_limit() -> None:
    """The old loophole: reset, reset, reset (from the CNC's register, or a restart) while
    the part stays oversize. The CNC's total stops at max_total from where it was."""
    evts = []
    for _ in range(10):
        evts += [("measure", 3), ("reset_modbus", None), ("restart", None)]
    cnc, loop, _ = run_loop(evts, [], deviation_mm=0.02)
    assert cnc.total_mm == pytest.approx(-LIVE.max_total_mm)
    assert any(d.kind is Kind.LIMIT for d in loop.decisions)
    refused = [d for d in loop.decisions if d.code == "reset_refused"]
    assert len(refused) == 10 and all(d.who == "modbus" for d in refused)


def test_a_technicians_reset_moves_the_reference() -> None:
    evts = [("measure", 9), ("reset_api", None), ("measure", 9)]
    cnc, loop, _ = run_loop(evts, [], deviation_mm=0.02)
    assert cnc.total_mm == pytest.approx(-2 * LIVE.max_total_mm)
    resets = [d for d in loop.decisions if d.kind is Kind.RESET]
    assert len(resets) == 1 and resets[0].who == "api:technician"


def test_no_offset_before_the_cnc_total_is_known() -> None:
    c = CompensationController(LIVE)
    for i in range(4):
        d = c.on_measurement(MeasurementIn(i, 100.0 + i, "ok", 30.008, 0.001), 100.0 + i)
    assert d.kind is Kind.HELD and d.code == "cnc_total_unknown"
    assert c.observe_cnc_total(0.05, 105.0).kind is Kind.BASELINE
    assert c.persisted.baseline_mm == 0.05


def test_the_fresh_total_is_checked_before_the_write() -> None:
    """Someone moved the CNC's wear offset by hand since the last reading: the offset that
    would now take it beyond the limit is not written."""
    c = CompensationController(LIVE)
    c.observe_cnc_total(0.0, 100.0)
    for i in range(2):
        d = c.on_measurement(MeasurementIn(i, 100.0 + i, "ok", 30.008, 0.001), 100.0 + i)
    assert d.kind is Kind.WRITE
    veto = c.check_before_write(d.offset_seq, -0.028, 103.0)
    assert veto is not None and veto.kind is Kind.LIMIT and "beyond the limit" in veto.reason
    assert c.state is State.ACTIVE and c.persisted.pending_seq is None
    assert c.check_before_write(d.offset_seq, 0.0, 104.0).code == "not_in_flight"


def test_enabling_while_an_offset_is_unsettled_is_refused() -> None:
    c = CompensationController(LIVE)
    c.observe_cnc_total(0.0, 100.0)
    for i in range(2):
        d = c.on_measurement(MeasurementIn(i, 100.0 + i, "ok", 30.008, 0.001), 100.0 + i)
    c.on_write_outcome(d.offset_seq, None, 103.0)
    c.update_settings(replace(LIVE, shadow=True), 104.0)
    with pytest.raises(ValueError, match="unsettled"):
        c.update_settings(LIVE, 105.0)


def test_measurements_of_another_calibration_are_refused() -> None:
    c = CompensationController(LIVE, calibration_id=7)
    d = c.on_measurement(MeasurementIn(1, 100.0, "ok", 30.0, 0.001, calibration_id=6), 100.0)
    assert d.kind is Kind.REFUSED and d.code == "other_calibration"
    assert "calibration 6" in d.reason and "7 is active" in d.reason


def test_every_outcome_names_the_measurement_its_offset_answers() -> None:
    """The trend ties each applied offset to the measurement it answered: an offset settled
    late from the CNC's registers (as the pull handshake settles every offset) names it as
    one acknowledged at once does."""
    _, loop, _ = run_loop([("measure", 2), ("measure", 3)] + [("tick", None)] * 2, [3, 0])
    writes = {d.offset_seq: d.measurement_seq for d in loop.decisions if d.kind is Kind.WRITE}
    outcomes = [d for d in loop.decisions
                if d.kind in (Kind.APPLIED, Kind.UNCERTAIN, Kind.NOT_APPLIED)]
    assert outcomes and all(d.measurement_seq is not None for d in outcomes), outcomes
    assert all(d.measurement_seq == writes[d.offset_seq] for d in outcomes), outcomes
