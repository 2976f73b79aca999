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
from drivers.plc.registers import UM_PER_UNIT, RegisterBank
from service.compensation import CncReading

OFFSET_BIAS = 1 << 15
TOTAL_BIAS = 1 << 30
REQUEST_KEY = 0x5A5A
REPORT_KEY = 0xA5A5
REQUEST = ("request_seq", "request_offset", "request_base_hi", "request_base_lo",
           "request_check")
REPORT = ("cnc_ack", "cnc_result", "cnc_total_hi", "cnc_total_lo", "cnc_check")


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


def request_check(seq: int, offset: int, base_hi: int, base_lo: int) -> int:
    """The request block's check word."""
    return (seq + offset + base_hi + base_lo + REQUEST_KEY) & 0xFFFF


def report_check(ack: int, result: int, total_hi: int, total_lo: int) -> int:
    """The report block's check word."""
    return (ack + result + total_hi + total_lo + REPORT_KEY) & 0xFFFF


@dataclass(frozen=True)
class Request:
    """An offset request as posted (controller sequence, offset and base in 0.1 um)."""

    seq: int
    offset_units: int
    base_units: int

    def words(self) -> dict[str, int]:
        """The request registers' values."""
        if not -OFFSET_BIAS <= self.offset_units < OFFSET_BIAS:
            raise ValueError(f"offset {self.offset_units} x 0.1 um is beyond the pull "
                             f"encoding (+-3.2768 mm)")
        seq, offset = wire_seq(self.seq), self.offset_units + OFFSET_BIAS
        hi, lo = total_words(self.base_units)
        return dict(zip(REQUEST, (seq, offset, hi, lo, request_check(seq, offset, hi, lo)),
                        strict=True))


@dataclass(frozen=True)
class Report:
    """The CNC's report, as read from the gauge's registers."""

    ack: int          # 16-bit request sequence it settled last (0: none)
    result: Result
    total_units: int  # its total, 0.1 um of diameter

    @property
    def total_mm(self) -> float:
        """Its total, mm of diameter."""
        return self.total_units * UM_PER_UNIT / 1000.0


def read_report(bank: RegisterBank) -> Report | None:
    """The CNC's report in ``bank``, or None when there is none whole (never written, torn,
    or an unknown result code)."""
    ack, result, hi, lo, check = (bank.get(name) for name in REPORT)
    if check != report_check(ack, result, hi, lo) or result not in Result._value2member_map_:
        return None
    return Report(ack, Result(result), total_units(hi, lo))


def read_request(bank: RegisterBank) -> tuple[int, int, int] | None:
    """The request in ``bank`` as the CNC reads it: (16-bit sequence, offset and base in
    0.1 um), or None when there is none or it is not whole."""
    seq, offset, hi, lo, check = (bank.get(name) for name in REQUEST)
    if seq == 0 or check != request_check(seq, offset, hi, lo):
        return None
    return seq, offset - OFFSET_BIAS, total_units(hi, lo)


class PullCnc:
    """The gauge's side of the pull handshake over its own register bank.

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
        self._last_total: int | None = None
        self.last_error = ""
        self.outage_since: float | None = None

    @property
    def connected(self) -> bool:
        """Whether the CNC has reported (a whole report is in the registers)."""
        return read_report(self.bank) is not None

    def post(self, request: Request | None) -> None:
        """Post ``request`` (None withdraws the one posted)."""
        self.posted = request
        self.bank.set_many(request.words() if request is not None
                           else dict.fromkeys(REQUEST, 0))

    async def read_cnc(self) -> CncReading | None:
        """The CNC's side: the posted request's sequence while it waits for an answer (0 once
        the CNC refused it or none is posted), the sequence the CNC applied, its total; None
        while the CNC has not reported."""
        report = read_report(self.bank)
        if report is None:
            self.last_error = "the CNC has not reported in the pull registers"
            if self.outage_since is None:
                self.outage_since = self.clock()
            return None
        self.outage_since = None
        self._last_total = report.total_units
        posted = self.posted
        answered = posted is not None and report.ack == wire_seq(posted.seq)
        ack = posted.seq if answered and report.result is Result.APPLIED else 0
        request = 0 if posted is None or (answered and report.result is Result.NOT_APPLIED) \
            else posted.seq
        return CncReading(ack, request, report.total_mm)

    async def write_offset(self, offset_mm: float, seq: int) -> WriteResult:
        """Post one offset and wait for the CNC's answer.

        APPLIED or NOT_APPLIED as the CNC reports it (the request is then withdrawn); UNKNOWN
        when it has not answered within ``ack_timeout_s`` (the request stays posted: the CNC
        still applies it once, and ``read_cnc`` settles it); NOT_APPLIED at once when the
        CNC has never reported (there is no total to apply to).
        """
        t0 = self.clock()
        units = round(offset_mm * 1000.0 / UM_PER_UNIT)

        def result(outcome: Outcome, message: str) -> WriteResult:
            return WriteResult(outcome, seq, units, message, self.clock() - t0)

        report = read_report(self.bank)
        if report is None:
            return result(Outcome.NOT_APPLIED, "the CNC has not reported in the pull "
                          "registers (is its Modbus client polling the gauge?)")
        base = self._last_total if self._last_total is not None else report.total_units
        try:
            self.post(Request(seq, units, base))
        except ValueError as err:
            return result(Outcome.NOT_APPLIED, str(err))
        wire = wire_seq(seq)
        while self.clock() - t0 < self.ack_timeout_s:
            await asyncio.sleep(self.poll_s)
            report = read_report(self.bank)
            if report is None or report.ack != wire:
                continue
            self.post(None)
            if report.result is Result.APPLIED:
                return result(Outcome.APPLIED, "the CNC applied it and reported its total")
            return result(Outcome.NOT_APPLIED, f"the CNC did not apply it: its total "
                          f"({report.total_units} x 0.1 um) was not the request's base "
                          f"({base})")
        return result(Outcome.UNKNOWN, f"no answer from the CNC within "
                      f"{self.ack_timeout_s:g} s (the request stays posted)")

    async def resume(self, seq: int, offset_mm: float, base_mm: float) -> None:
        """Post an offset again whose fate was unknown when the gauge stopped (same
        sequence, offset and base: the CNC applies it at most once, and answers)."""
        self.post(Request(seq, round(offset_mm * 1000.0 / UM_PER_UNIT),
                          round(base_mm * 1000.0 / UM_PER_UNIT)))


def settle_request(bank: RegisterBank, total_units_now: int, settled: int | None
                   ) -> tuple[Result, int, int | None]:
    """What a polling CNC does with the request in ``bank`` (the rules the NC subroutine in
    ``deploy/linuxcnc`` follows; pure, for its simulation and the tests): given its total
    (0.1 um) and the 16-bit sequence it settled last (None after its restart), returns the
    result, its total after, and the sequence it reports (None when there was nothing to
    settle)."""
    request = read_request(bank)
    if request is None or request[0] == settled:
        return Result.NONE, total_units_now, None
    seq, offset, base = request
    if total_units_now == base:
        return Result.APPLIED, base + offset, seq
    if total_units_now == base + offset:
        return Result.APPLIED, total_units_now, seq
    return Result.NOT_APPLIED, total_units_now, seq


def write_report(bank: RegisterBank, ack: int, result: Result, total: int) -> None:
    """Write a CNC's report into ``bank`` as its Modbus client would."""
    hi, lo = total_words(total)
    bank.set_many(dict(zip(REPORT, (ack, int(result), hi, lo,
                                    report_check(ack, int(result), hi, lo)), strict=True)))
