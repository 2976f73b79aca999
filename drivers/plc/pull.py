"""The pull handshake: tool-wear offsets for a CNC that can only poll.

mb2hal (LinuxCNC's Modbus client) and many PLCs' Modbus clients cannot be written to: they
read and write a server's registers on their own schedule, 16 unsigned bits a register. So
the gauge posts the offset as a request in its own registers (``request_*``, map version 2)
and the CNC reports back into them (``cnc_*``); ``PullCnc`` is the gauge's side, an
``OffsetTransport`` like the push writer (``drivers.plc.client.OffsetWriter``).

Exactly once by compare-and-set on the CNC's side. A request names the total it applies to
(its *base*: the CNC's total as the CNC last reported it), and the CNC, finding a request with
a sequence it has not settled (or any, after its own restart):

- total == base: applies it (total becomes base + offset) and reports APPLIED;
- total == base + offset: it was applied already (the CNC or the gauge restarted before the
  report arrived): reports APPLIED and applies nothing;
- otherwise: reports NOT_APPLIED, certainly not applied.

Map version 4 carries the tool: ``request_tool`` names the T number a request is for and
``cnc_tool`` the one a report's total is of (0 in both: the one tool of a job with one, as in
version 3, whose CNCs compute the same check words). A CNC applies a request only when called
for its tool. The one request block serves the tools in turn: a tool's request waits behind
another's until the CNC has answered it (``PullCnc.tool``).

Map version 5 carries the offset entry: ``request_entry`` names the offset number a request
corrects (0: the tool's own entry) and ``cnc_entry`` the one a report's total is of; a CNC
applies a request only when called for its tool and entry. Each adds into its check word,
so a CNC of version 4 refuses a request for another entry as torn, and the gauge posts one
only to a CNC that says it is of version 5 (``cnc_version``): ``PullCnc.entry``.

Posting the same request again can therefore never apply it twice, and every request gets an
answer that settles it: the gauge posts its unsettled offset again after its own restart
(``resume``). Encodings (all unsigned 16-bit):

- sequence: 1-65535, the controller's sequence wrapped past 0 (``wire_seq``); 0 no request;
- offset: 0.1 um of diameter plus 32768 (+-3.2768 mm);
- totals: 0.1 um of diameter plus 2^30, in a high and a low word (+-107 m);
- check words: the block's sum plus a constant, mod 65536 (``request_check``,
  ``report_check``); a block read while it was being written, or never written (all 0), has
  the wrong check and is not taken.
"""

from __future__ import annotations

import asyncio
import enum
import time
from collections.abc import Callable
from dataclasses import dataclass

from drivers.plc.client import Outcome, WriteResult
from drivers.plc.registers import CNC_VERSION, UM_PER_UNIT, RegisterBank
from service.compensation import CncReading

OFFSET_BIAS = 1 << 15
TOTAL_BIAS = 1 << 30
REQUEST_KEY = 0x5A5A
REPORT_KEY = 0xA5A5
REQUEST = ("request_seq", "request_offset", "request_base_hi", "request_base_lo",
           "request_check", "request_tool", "request_entry")
REPORT = ("cnc_ack", "cnc_result", "cnc_total_hi", "cnc_total_lo", "cnc_check", "cnc_tool",
          "cnc_entry")


class Result(enum.IntEnum):
    """Codes of ``cnc_result``."""

    NONE = 0
    APPLIED = 1
    NOT_APPLIED = 2   # the CNC's total was not the request's base


def wire_seq(seq: int) -> int:
    """The controller's sequence (1, 2, ...) as a 16-bit request sequence: 1-65535, wrapping
    past 0 (0 is no request)."""
    return (int(seq) - 1) % 0xFFFF + 1


def total_words(units: int) -> tuple[int, int]:
    """A total (0.1 um of diameter) as (high, low) words of its biased value."""
    if not -TOTAL_BIAS <= units < TOTAL_BIAS:
        raise ValueError(f"total {units} x 0.1 um is beyond the pull encoding (+-107 m)")
    raw = int(units) + TOTAL_BIAS
    return raw >> 16, raw & 0xFFFF


def total_units(hi: int, lo: int) -> int:
    """The total (0.1 um of diameter) of (high, low) words."""
    return (int(hi) << 16 | int(lo)) - TOTAL_BIAS


def request_check(seq: int, offset: int, base_hi: int, base_lo: int, tool: int = 0,
                  entry: int = 0) -> int:
    """The request block's check word (its tool and entry add in: 0, as version 3 computes
    it)."""
    return (seq + offset + base_hi + base_lo + tool + entry + REQUEST_KEY) & 0xFFFF


def report_check(ack: int, result: int, total_hi: int, total_lo: int, tool: int = 0,
                 entry: int = 0) -> int:
    """The report block's check word (its tool and entry add in: 0, as version 3 computes
    it)."""
    return (ack + result + total_hi + total_lo + tool + entry + REPORT_KEY) & 0xFFFF


@dataclass(frozen=True)
class Request:
    """An offset request as posted (controller sequence, offset and base in 0.1 um, the
    tool's T number or 0, the offset entry or 0 for the tool's own)."""

    seq: int
    offset_units: int
    base_units: int
    tool: int = 0
    entry: int = 0

    @property
    def key(self) -> tuple[int, int]:
        """(tool, entry): whose request it is."""
        return self.tool, self.entry

    def words(self) -> dict[str, int]:
        """The request registers' values."""
        if not -OFFSET_BIAS <= self.offset_units < OFFSET_BIAS:
            raise ValueError(f"offset {self.offset_units} x 0.1 um is beyond the pull "
                             f"encoding (+-3.2768 mm)")
        seq, offset = wire_seq(self.seq), self.offset_units + OFFSET_BIAS
        hi, lo = total_words(self.base_units)
        return dict(zip(REQUEST, (seq, offset, hi, lo,
                                  request_check(seq, offset, hi, lo, self.tool, self.entry),
                                  self.tool, self.entry), strict=True))


@dataclass(frozen=True)
class Report:
    """The CNC's report, as read from the gauge's registers."""

    ack: int          # 16-bit request sequence it settled last (0: none)
    result: Result
    total_units: int  # its total, 0.1 um of diameter
    tool: int = 0     # the T number it reports for (0: one tool, map v3)
    entry: int = 0    # the offset entry it reports for (0: the tool's own)

    @property
    def total_mm(self) -> float:
        """Its total, mm of diameter."""
        return self.total_units * UM_PER_UNIT / 1000.0


def read_report(bank: RegisterBank) -> Report | None:
    """The CNC's report in ``bank``, or None when there is none whole (never written, torn,
    or an unknown result code)."""
    ack, result, hi, lo, check, tool, entry = (bank.get(name) for name in REPORT)
    if check != report_check(ack, result, hi, lo, tool, entry) or \
            result not in Result._value2member_map_:
        return None
    return Report(ack, Result(result), total_units(hi, lo), tool, entry)


def read_request(bank: RegisterBank, tool: int = 0, entry: int = 0
                 ) -> tuple[int, int, int] | None:
    """The request in ``bank`` as the CNC called for ``tool`` and its ``entry`` reads it:
    (16-bit sequence, offset and base in 0.1 um), or None when there is none, it is not
    whole, or it is for another tool or entry (tool 0 in the request: for whichever tool the
    CNC compensates)."""
    seq, offset, hi, lo, check, for_tool, for_entry = (bank.get(name) for name in REQUEST)
    if seq == 0 or check != request_check(seq, offset, hi, lo, for_tool, for_entry) or \
            for_tool not in (0, tool) or for_entry != entry:
        return None
    return seq, offset - OFFSET_BIAS, total_units(hi, lo)


class PullCnc:
    """The gauge's side of the pull handshake over its own register bank: itself the
    transport of a job with one tool (tool 0 on the wire), ``entry(t, n)`` that of tool
    ``t``'s offset entry ``n`` (``tool(t)``: its own).

    Parameters
    ----------
    bank : RegisterBank
        The registers the gauge's Modbus server serves (the CNC polls them).
    host, port : str, int
        Where that server listens (for the status: the CNC comes to the gauge).
    ack_timeout_s : float
        How long ``write_offset`` waits for the CNC's answer before calling the offset's fate
        unknown (a CNC polls when its program calls for it: a part's cycle can be longer).
    poll_s : float
        How often the bank is looked at meanwhile.
    clock : callable
        Monotonic seconds.
    """

    def __init__(self, bank: RegisterBank, host: str = "", port: int = 0,
                 ack_timeout_s: float = 3.0, poll_s: float = 0.02,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.bank, self.host, self.port = bank, host, port
        self.ack_timeout_s, self.poll_s, self.clock = ack_timeout_s, poll_s, clock
        self.posted: Request | None = None
        self.last_error = ""
        self.outage_since: float | None = None
        self._waiting: list[Request] = []  # behind the posted one, in turn
        self._totals: dict[tuple[int, int], int] = {}  # each entry's total as last reported
        self._latest: int | None = None  # the total last reported of a tool's own entry
        self._answers: dict[tuple[int, int], tuple[int, Result]] = {}  # each entry's last
        self._entries: dict[tuple[int, int], PullEntry] = {}

    @property
    def connected(self) -> bool:
        """Whether the CNC has reported (a whole report is in the registers)."""
        return read_report(self.bank) is not None

    def knows_entries(self) -> bool:
        """Whether the CNC says its subroutine applies offset entries (map version 5)."""
        return self.bank.get("cnc_version") >= CNC_VERSION

    def entry(self, tool: int, number: int = 0) -> PullEntry:
        """The transport of tool ``tool``'s offset entry ``number`` (0: the tool's own)."""
        key = (tool, number)
        if key not in self._entries:
            self._entries[key] = PullEntry(self, tool, number)
        return self._entries[key]

    def tool(self, number: int) -> PullEntry:
        """The transport of tool ``number``'s own entry."""
        return self.entry(number)

    def post(self, request: Request | None) -> None:
        """Show ``request`` in the request registers (None: withdraw the one shown)."""
        self.posted = request
        self.bank.set_many(request.words() if request is not None
                           else dict.fromkeys(REQUEST, 0))

    def offer(self, request: Request) -> None:
        """Post ``request``, or queue it behind the one posted for another entry (one of the
        same entry is replaced: an entry has one offset in flight)."""
        self._waiting = [r for r in self._waiting if r.key != request.key]
        if self.posted is None or self.posted.key == request.key:
            self.post(request)
        else:
            self._waiting.append(request)

    def pending(self, key: tuple[int, int]) -> Request | None:
        """The request of entry ``key`` (tool, entry) posted or waiting, if any."""
        for r in ([self.posted] if self.posted else []) + self._waiting:
            if r.key == key:
                return r
        return None

    def look(self) -> Report | None:
        """Read the CNC's report: note its entry's total, and the answer to the posted
        request (which is then withdrawn, the next one posted)."""
        report = read_report(self.bank)
        if report is None:
            self.last_error = "the CNC has not reported in the pull registers"
            if self.outage_since is None:
                self.outage_since = self.clock()
            return None
        self.outage_since = None
        self._totals[report.tool, report.entry] = report.total_units
        if report.entry == 0:
            self._latest = report.total_units
        posted = self.posted
        # A request for tool 0 is for whichever tool the CNC compensates (map v3).
        if posted is not None and posted.tool in (0, report.tool) and \
                posted.entry == report.entry and report.ack == wire_seq(posted.seq) and \
                report.result is not Result.NONE:
            self._answers[posted.key] = (posted.seq, report.result)
            self.post(self._waiting.pop(0) if self._waiting else None)
        return report

    async def close(self) -> None:
        """Nothing to close: the CNC comes to the gauge's own server (stopped with it)."""

    async def watch(self, period_s: float = 0.05) -> None:
        """Look at the report every ``period_s`` until cancelled: an answer withdraws its
        request at once and posts the next entry's, before the CNC calls for that one."""
        while True:
            self.look()
            await asyncio.sleep(period_s)

    async def read_cnc(self) -> CncReading | None:
        """Tool 0's side (a job with one tool): see ``PullEntry.read_cnc``."""
        return await self.tool(0).read_cnc()

    async def write_offset(self, offset_mm: float, seq: int) -> WriteResult:
        """Tool 0's offset (a job with one tool): see ``PullEntry.write_offset``."""
        return await self.tool(0).write_offset(offset_mm, seq)

    async def resume(self, seq: int, offset_mm: float, base_mm: float) -> None:
        """Tool 0's unsettled offset again: see ``PullEntry.resume``."""
        await self.tool(0).resume(seq, offset_mm, base_mm)


class PullEntry:
    """One offset entry's transport over the shared request block (``PullCnc.entry``)."""

    def __init__(self, cnc: PullCnc, tool: int, number: int = 0) -> None:
        self.cnc, self.tool, self.number = cnc, tool, number
        self.read_total: int | None = None  # as ``read_cnc`` gave it (checked against limits)

    @property
    def key(self) -> tuple[int, int]:
        """(tool, entry) as on the wire."""
        return self.tool, self.number

    def __str__(self) -> str:
        return f"tool {self.tool}" + (f" offset {self.number}" if self.number else "")

    def total(self) -> int | None:
        """The entry's total as last reported (tool 0: the CNC's one tool's)."""
        return self.cnc._latest if self.tool == 0 else self.cnc._totals.get(self.key)

    async def read_cnc(self) -> CncReading | None:
        """The CNC's side for this entry: its request's sequence while it waits for an answer
        (posted or queued; 0 once the CNC refused it or none is), the sequence the CNC
        applied, the entry's total as last reported; None while the CNC has not reported, or
        not yet for this entry."""
        if self.cnc.look() is None:
            return None
        total = self.total()
        if total is None:
            self.cnc.last_error = f"the CNC has not reported {self}'s total yet"
            return None
        self.read_total = total
        waiting = self.cnc.pending(self.key)
        seq, result = self.cnc._answers.get(self.key, (0, Result.NONE))
        if waiting is not None:
            return CncReading(0, waiting.seq, total * UM_PER_UNIT / 1000.0)
        ack = seq if result is Result.APPLIED else 0
        return CncReading(ack, 0, total * UM_PER_UNIT / 1000.0)

    async def write_offset(self, offset_mm: float, seq: int) -> WriteResult:
        """Offer one offset and wait for the CNC's answer.

        APPLIED or NOT_APPLIED as the CNC reports it (the request is then withdrawn); UNKNOWN
        when it has not answered within ``ack_timeout_s`` (the request stays posted, or
        queued behind another entry's: the CNC still applies it once, and ``read_cnc``
        settles it); NOT_APPLIED at once when the CNC has never reported this entry's total
        (there is nothing to apply to), or it is another entry than the tool's own and the
        CNC's subroutine is older than map version 5 (it could not apply it).
        """
        cnc = self.cnc
        t0 = cnc.clock()
        units = round(offset_mm * 1000.0 / UM_PER_UNIT)

        def result(outcome: Outcome, message: str) -> WriteResult:
            return WriteResult(outcome, seq, units, message, cnc.clock() - t0)

        reported = cnc.look() is not None
        if self.number and not cnc.knows_entries():
            return result(Outcome.NOT_APPLIED, f"the CNC's subroutine does not apply offset "
                          f"entries (cnc_version {cnc.bank.get('cnc_version')}, map version "
                          f"{CNC_VERSION} needed): {self}'s offset was not posted; install "
                          "the version 5 subroutine and link (deploy/linuxcnc)")
        # The base: the total the channel read and checked just before, as the CNC reported it.
        base = self.read_total if self.read_total is not None else self.total()
        if base is None or not reported:
            return result(Outcome.NOT_APPLIED, "the CNC has not reported in the pull "
                          "registers (is its Modbus client polling the gauge?)"
                          if not reported else f"the CNC has not reported {self}'s total "
                          "yet (its subroutine reports the tool and entry it is called for)")
        try:
            cnc.offer(Request(seq, units, base, self.tool, self.number))
        except ValueError as err:
            return result(Outcome.NOT_APPLIED, str(err))
        while cnc.clock() - t0 < cnc.ack_timeout_s:
            await asyncio.sleep(cnc.poll_s)
            cnc.look()
            answered, outcome = cnc._answers.get(self.key, (0, Result.NONE))
            if answered != seq or cnc.pending(self.key) is not None:
                continue
            if outcome is Result.APPLIED:
                return result(Outcome.APPLIED, "the CNC applied it and reported its total")
            return result(Outcome.NOT_APPLIED, f"the CNC did not apply it: its total "
                          f"({self.total()} x 0.1 um) was not the "
                          f"request's base ({base})")
        ahead = cnc.posted.key if cnc.posted is not None else self.key
        where = "posted" if ahead == self.key else \
            f"queued behind {cnc.entry(*ahead)}'s"
        return result(Outcome.UNKNOWN, f"no answer from the CNC within "
                      f"{cnc.ack_timeout_s:g} s (the request stays {where})")

    async def resume(self, seq: int, offset_mm: float, base_mm: float) -> None:
        """Offer an offset again whose fate was unknown when the gauge stopped (same
        sequence, offset and base: the CNC applies it at most once, and answers)."""
        self.cnc.offer(Request(seq, round(offset_mm * 1000.0 / UM_PER_UNIT),
                               round(base_mm * 1000.0 / UM_PER_UNIT), self.tool, self.number))


def settle_request(bank: RegisterBank, total_units_now: int, settled: int | None,
                   tool: int = 0, entry: int = 0) -> tuple[Result, int, int | None]:
    """What a polling CNC does with the request in ``bank`` (the rules the NC subroutine in
    ``deploy/linuxcnc`` follows; pure, for its simulation and the tests): given its total
    (0.1 um) and the 16-bit sequence it settled last (None after its restart), returns the
    result, its total after, and the sequence it reports (None when there was nothing to
    settle). ``tool``: the T number it is called for (0: a CNC of map v3); ``entry`` the
    offset entry (0: the tool's own)."""
    request = read_request(bank, tool, entry)
    if request is None or request[0] == settled:
        return Result.NONE, total_units_now, None
    seq, offset, base = request
    if total_units_now == base:
        return Result.APPLIED, base + offset, seq
    if total_units_now == base + offset:
        return Result.APPLIED, total_units_now, seq
    return Result.NOT_APPLIED, total_units_now, seq


def write_report(bank: RegisterBank, ack: int, result: Result, total: int, tool: int = 0,
                 entry: int = 0) -> None:
    """Write a CNC's report (for ``tool``'s ``entry``'s total) into ``bank`` as its Modbus
    client would (a CNC that reports an entry says it is of map version 5)."""
    hi, lo = total_words(total)
    bank.set_many({"cnc_version": CNC_VERSION if entry else bank.get("cnc_version"),
                   **dict(zip(REPORT, (ack, int(result), hi, lo,
                                       report_check(ack, int(result), hi, lo, tool, entry),
                                       tool, entry), strict=True))})
