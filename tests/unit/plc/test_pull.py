"""The pull handshake (drivers/plc/pull.py): its encodings, the CNC's compare-and-set rules,
the gauge's transport against a polling CNC, and the same exactly-once properties as the push
handshake (tests/unit/test_cnc_loop.py) over CNC and gauge restarts, lost polls and torn
reads."""

from __future__ import annotations

import asyncio
import json
from dataclasses import asdict, dataclass, field

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.plc import pull
from drivers.plc.client import Outcome
from drivers.plc.pull import PullCnc, Result, read_report, settle_request, write_report
from drivers.plc.registers import RegisterBank
from service.compensation import (
    CompensationController,
    ControllerState,
    Decision,
    Kind,
    MeasurementIn,
    State,
)
from service.runtime.offset_channel import OffsetChannel
from tests.unit.test_cnc_loop import LIVE, Loop


@dataclass
class PolledNc:
    """A CNC that polls the gauge's pull registers when its program calls the subroutine:
    the rules of deploy/linuxcnc/shaftgauge_comp.ngc, in Python. ``total`` in 0.1 um."""

    total: int = 0
    settled: int | None = None       # 16-bit sequence settled last; None after a restart
    result: Result = Result.NONE
    applied: list = field(default_factory=list)

    def poll(self, bank: RegisterBank) -> None:
        result, total, seq = settle_request(bank, self.total, self.settled)
        if seq is not None:
            if total != self.total:
                assert seq not in self.applied, f"request {seq} applied twice"
                self.applied.append(seq)
            self.total, self.settled, self.result = total, seq, result
        write_report(bank, self.settled or 0, self.result, self.total)

    def restart(self) -> None:
        """LinuxCNC restarted: the tool table (its total) is kept, nothing else."""
        self.settled, self.result = None, Result.NONE


def test_encodings_survive_sixteen_unsigned_bits() -> None:
    assert [pull.wire_seq(s) for s in (1, 65535, 65536, 65537, 131070)] == [1, 65535, 1, 2,
                                                                              65535]
    for units in (0, 1, -1, 123456, -2_000_000, (1 << 30) - 1, -(1 << 30)):
        hi, lo = pull.total_words(units)
        assert 0 <= hi <= 0xFFFF and 0 <= lo <= 0xFFFF
        assert pull.total_units(hi, lo) == units
    with pytest.raises(ValueError, match="beyond"):
        pull.total_words(1 << 30)
    words = pull.Request(70000, -123, -4567).words()
    assert all(0 <= v <= 0xFFFF for v in words.values())
    assert words["request_seq"] == pull.wire_seq(70000)
    assert words["request_offset"] == 32768 - 123
    with pytest.raises(ValueError, match=r"3\.2768 mm"):
        pull.Request(1, 40000, 0).words()


def test_a_report_is_taken_only_whole() -> None:
    bank = RegisterBank()
    assert read_report(bank) is None  # never written: all zero, the check is wrong
    write_report(bank, 7, Result.APPLIED, -250)
    assert read_report(bank) == pull.Report(7, Result.APPLIED, -250)
    bank.set("cnc_total_lo", bank.get("cnc_total_lo") + 1)  # torn: total new, check old
    assert read_report(bank) is None
    write_report(bank, 7, Result.APPLIED, -250)
    bank.set("cnc_result", 9)
    bank.set("cnc_check", pull.report_check(7, 9, *pull.total_words(-250)))
    assert read_report(bank) is None  # an unknown result code


def test_the_cnc_applies_a_request_to_its_base_once() -> None:
    bank = RegisterBank()
    PullCnc(bank).post(pull.Request(3, 40, 1000))
    assert settle_request(bank, 1000, None) == (Result.APPLIED, 1040, 3)   # applies
    assert settle_request(bank, 1040, None) == (Result.APPLIED, 1040, 3)   # already did
    assert settle_request(bank, 1040, 3) == (Result.NONE, 1040, None)     # settled: skip
    assert settle_request(bank, 990, None) == (Result.NOT_APPLIED, 990, 3)  # another base
    bank.set("request_offset", bank.get("request_offset") + 1)             # torn request
    assert settle_request(bank, 1000, None) == (Result.NONE, 1000, None)


def test_transport_against_a_polling_cnc() -> None:
    """Applied when the CNC answers in time; unknown when it does not, then settled from its
    report; refused (certainly) when its total moved; never posted without a report."""
    async def go() -> None:
        bank = RegisterBank()
        gauge = PullCnc(bank, ack_timeout_s=0.5, poll_s=0.005)
        nc = PolledNc(total=500)
        r = await gauge.write_offset(0.001, 1)
        assert r.outcome is Outcome.NOT_APPLIED and "not reported" in r.message
        nc.poll(bank)
        assert (await gauge.read_cnc()).total_mm == pytest.approx(0.05)

        async def cnc_polls() -> None:
            for _ in range(20):
                await asyncio.sleep(0.01)
                nc.poll(bank)

        poller = asyncio.create_task(cnc_polls())
        r = await gauge.write_offset(-0.0012, 1)
        await poller
        assert r.outcome is Outcome.APPLIED and nc.total == 488 and nc.applied == [1]
        assert bank.get("request_seq") == 0  # withdrawn once answered

        gauge.ack_timeout_s = 0.05
        await gauge.read_cnc()
        r = await gauge.write_offset(0.002, 2)
        assert r.outcome is Outcome.UNKNOWN and bank.get("request_seq") == 2
        reading = await gauge.read_cnc()
        assert (reading.ack_seq, reading.request_seq) == (0, 2)  # cannot tell yet
        nc.poll(bank)
        reading = await gauge.read_cnc()
        assert (reading.ack_seq, reading.total_mm) == (2, pytest.approx(0.0508))

        await gauge.read_cnc()
        r = await gauge.write_offset(0.001, 3)   # base 508 ...
        nc.total = 400                            # ... but someone moved the offset by hand
        nc.poll(bank)
        reading = await gauge.read_cnc()
        assert (reading.ack_seq, reading.request_seq) == (0, 0)  # refused: not applied
        assert nc.total == 400 and nc.applied == [1, 2]

    asyncio.run(go())


def test_two_tools_take_the_request_block_in_turn() -> None:
    """A request names its tool; a CNC called for another tool leaves it; a second tool's
    request waits behind the first until the CNC answered that, then is posted; each tool's
    view reads its own total and its own answers."""
    async def go() -> None:
        bank = RegisterBank()
        gauge = PullCnc(bank, ack_timeout_s=0.0)
        t1, t2 = gauge.tool(1), gauge.tool(2)
        write_report(bank, 0, Result.NONE, 500, tool=1)
        assert (await t1.read_cnc()).total_mm == pytest.approx(0.05)
        assert await t2.read_cnc() is None  # tool 2 has not reported
        r = await t2.write_offset(0.001, 1)
        assert r.outcome is Outcome.NOT_APPLIED and "tool 2's total" in r.message
        write_report(bank, 0, Result.NONE, 700, tool=2)
        assert (await t1.write_offset(-0.0012, 4)).outcome is Outcome.UNKNOWN
        r = await t2.write_offset(0.0009, 9)
        assert r.outcome is Outcome.UNKNOWN and "queued behind tool 1's" in r.message
        assert (bank.get("request_seq"), bank.get("request_tool")) == (4, 1)
        assert (await t2.read_cnc()).request_seq == 9  # waiting: cannot tell yet
        # The CNC called for tool 2 finds tool 1's request and leaves it.
        assert settle_request(bank, 700, None, tool=2) == (Result.NONE, 700, None)
        assert settle_request(bank, 500, None, tool=1) == (Result.APPLIED, 488, 4)
        write_report(bank, 4, Result.APPLIED, 488, tool=1)
        gauge.look()
        assert (bank.get("request_seq"), bank.get("request_tool")) == (9, 2)
        reading = await t1.read_cnc()
        assert (reading.ack_seq, reading.request_seq, reading.total_mm) == (
            4, 0, pytest.approx(0.0488))
        assert settle_request(bank, 700, None, tool=2) == (Result.APPLIED, 709, 9)
        write_report(bank, 9, Result.APPLIED, 709, tool=2)
        reading = await t2.read_cnc()
        assert (reading.ack_seq, reading.request_seq) == (9, 0)
        assert bank.get("request_seq") == 0
        assert (await t1.read_cnc()).ack_seq == 4  # its answer is kept

    asyncio.run(go())


def test_two_entries_of_one_tool_take_the_block_in_turn_each_with_its_total() -> None:
    """Map v5: a request names its entry; the CNC called for the tool's own entry leaves a
    request for another of its entries, and the other way round; each entry reads its own
    total and answers, and a second entry's request waits behind the first's."""
    async def go() -> None:
        bank = RegisterBank()
        gauge = PullCnc(bank, ack_timeout_s=0.0)
        own, pin = gauge.tool(2), gauge.entry(2, 10012)
        write_report(bank, 0, Result.NONE, 700, tool=2)
        gauge.look()  # the watcher's look at each report
        write_report(bank, 0, Result.NONE, -40, tool=2, entry=10012)  # and says: version 5
        assert gauge.knows_entries()
        assert (await pin.read_cnc()).total_mm == pytest.approx(-0.004)
        assert (await own.read_cnc()).total_mm == pytest.approx(0.07)
        assert (await pin.write_offset(-0.0012, 3)).outcome is Outcome.UNKNOWN
        r = await own.write_offset(0.0009, 5)
        assert r.outcome is Outcome.UNKNOWN and "queued behind tool 2 offset 10012's" in \
            r.message
        assert (bank.get("request_tool"), bank.get("request_entry")) == (2, 10012)
        # Called for the tool's own entry, the CNC leaves the pin's request; for the pin's,
        # it applies it to the pin's total only.
        assert settle_request(bank, 700, None, tool=2) == (Result.NONE, 700, None)
        assert settle_request(bank, -40, None, tool=2, entry=10012) == (
            Result.APPLIED, -52, 3)
        write_report(bank, 3, Result.APPLIED, -52, tool=2, entry=10012)
        gauge.look()
        assert (bank.get("request_seq"), bank.get("request_entry")) == (5, 0)
        assert (await pin.read_cnc()).ack_seq == 3
        assert (await own.read_cnc()).total_mm == pytest.approx(0.07)  # untouched

    asyncio.run(go())


def test_a_version_4_cnc_is_never_sent_another_entry_and_never_applies_one() -> None:
    """A CNC whose subroutine is of map v4 (``cnc_version`` 0) gets no request for an entry
    other than a tool's own: refused at once, naming the version needed. Were one posted, a
    v4 CNC reads it as torn (its check leaves the entry out) and applies nothing; a request
    for a tool's own entry has the checks a v4 CNC computes."""
    async def go() -> None:
        bank = RegisterBank()
        gauge = PullCnc(bank, ack_timeout_s=0.0)
        write_report(bank, 0, Result.NONE, 700, tool=2)
        assert not gauge.knows_entries()
        r = await gauge.entry(2, 10012).write_offset(-0.001, 1)
        assert r.outcome is Outcome.NOT_APPLIED and "cnc_version 0" in r.message
        assert bank.get("request_seq") == 0  # nothing posted
        assert (await gauge.tool(2).write_offset(-0.001, 2)).outcome is Outcome.UNKNOWN

    asyncio.run(go())
    bank = RegisterBank()
    PullCnc(bank).post(pull.Request(4, -10, 700, tool=2, entry=10012))
    seq, off, hi, lo, chk, tool = (bank.get(n) for n in pull.REQUEST[:6])
    assert chk != (seq + off + hi + lo + tool + pull.REQUEST_KEY) & 0xFFFF  # v4: torn
    PullCnc(bank).post(pull.Request(4, -10, 700, tool=2))
    seq, off, hi, lo, chk, tool = (bank.get(n) for n in pull.REQUEST[:6])
    assert chk == (seq + off + hi + lo + tool + pull.REQUEST_KEY) & 0xFFFF  # v4: whole


def test_a_version_3_cnc_computes_the_same_checks_for_one_tool() -> None:
    """Tool 0 adds nothing to the check words: a CNC written for map v3 reads the request
    and writes its report as it did."""
    bank = RegisterBank()
    PullCnc(bank).post(pull.Request(5, 10, 2000))
    words = [bank.get(n) for n in pull.REQUEST[:4]]
    assert bank.get("request_check") == (sum(words) + pull.REQUEST_KEY) & 0xFFFF
    assert pull.report_check(5, 1, 3, 4) == (5 + 1 + 3 + 4 + pull.REPORT_KEY) & 0xFFFF
    assert pull.read_request(bank, tool=7) is not None  # for whichever tool calls


class PullLoop:
    """The gauge's side: a channel over a fresh bank after each restart (the service's
    registers start empty), offering an unsettled offset again as the service does."""

    def __init__(self, nc: PolledNc) -> None:
        self.nc, self.now = nc, 1000.0
        self.decisions: list[Decision] = []
        self.persisted = ControllerState()
        self.settings = LIVE
        self.seq = 0
        self.posted: list[int] = []
        self.restart_gauge()

    def restart_gauge(self) -> None:
        self.bank = RegisterBank()
        self.transport = PullCnc(self.bank, ack_timeout_s=0.0)
        post = self.transport.post

        def counting(request: pull.Request | None) -> None:
            if request is not None:
                self.posted.append(request.seq)
            post(request)

        self.transport.post = counting  # type: ignore[method-assign]
        state = ControllerState(**json.loads(json.dumps(asdict(self.persisted))))
        c = CompensationController(self.settings, state)
        self.persisted = c.persisted
        self.channel = OffsetChannel(c, self.transport, None,
                                     on_decision=self.decisions.append, clock=lambda: self.now)

    tick = Loop.settler_tick  # what ``run_settler`` does once, as for the push handshake


pull_events = st.lists(st.one_of(
    st.tuples(st.just("measure"), st.integers(1, 8)),
    st.tuples(st.just("cnc_polls"), st.none()),
    st.tuples(st.just("cnc_restarts"), st.none()),
    st.tuples(st.just("gauge_restarts"), st.none()),
    st.tuples(st.just("tick"), st.none()),
    st.tuples(st.just("torn"), st.none()),
), min_size=10, max_size=120)


def run_pull(evts: list, deviation_mm: float, start_units: int) -> tuple[PolledNc, PullLoop]:
    nc = PolledNc(total=start_units)
    loop = PullLoop(nc)

    async def go() -> None:
        nc.poll(loop.bank)
        await loop.tick()
        for what, arg in evts:
            if what == "measure":
                for _ in range(arg):
                    loop.seq += 1
                    loop.now += 1.0
                    await loop.channel.on_measurement(MeasurementIn(
                        loop.seq, loop.now, "ok", 30.0 + deviation_mm, 0.001))
            elif what == "cnc_polls":
                nc.poll(loop.bank)
            elif what == "cnc_restarts":
                nc.restart()
                # Its Modbus client writes zeros until the subroutine runs: no report.
                loop.bank.set_many(dict.fromkeys(pull.REPORT, 0))
            elif what == "gauge_restarts":
                loop.restart_gauge()
                await loop.channel.resume()
            elif what == "torn":  # a report read while the CNC was writing it
                loop.bank.set("cnc_total_lo", (loop.bank.get("cnc_total_lo") + 7) & 0xFFFF)
            elif what == "tick":
                await loop.tick()
        for _ in range(4):  # the CNC keeps polling, the gauge settles
            nc.poll(loop.bank)
            await loop.tick()

    asyncio.run(go())
    return nc, loop


@settings(max_examples=250, deadline=None)
@given(pull_events, st.sampled_from([-0.02, -0.008, 0.008, 0.02]), st.integers(-3000, 3000))
def test_pull_no_offset_twice_and_the_log_adds_up_to_the_cnc(evts, dev, start) -> None:
    nc, loop = run_pull(evts, dev, start)
    applied_log = [d for d in loop.decisions if d.kind is Kind.APPLIED]
    assert sorted(pull.wire_seq(d.offset_seq) for d in applied_log) == sorted(nc.applied)
    total_mm = (nc.total - start) * 1e-4
    assert sum(d.offset_mm for d in applied_log) == pytest.approx(total_mm, abs=1e-9)
    assert loop.channel.controller.state is not State.UNCERTAIN  # all settled in the end
    written = [d.offset_seq for d in loop.decisions if d.kind is Kind.WRITE]
    assert len(written) == len(set(written))
    # Posted only what was ordered (a write vetoed before it goes out is never posted).
    assert set(loop.posted) <= set(written)


def test_an_offset_applied_while_the_gauge_was_down_is_settled_as_applied() -> None:
    """The gauge posts, dies before the CNC polls; the CNC applies it; the restarted gauge
    (empty registers) offers it again: the CNC answers APPLIED and applies nothing more."""
    evts = [("measure", 2), ("cnc_polls", None), ("gauge_restarts", None), ("tick", None),
            ("cnc_polls", None), ("tick", None)]
    nc, loop = run_pull(evts, 0.008, 0)
    kinds = [d.kind for d in loop.decisions if d.kind in (Kind.WRITE, Kind.UNCERTAIN,
                                                         Kind.APPLIED, Kind.NOT_APPLIED)]
    assert kinds[:3] == [Kind.WRITE, Kind.UNCERTAIN, Kind.APPLIED], kinds
    assert nc.applied == [1] and loop.posted[:2] == [1, 1]
