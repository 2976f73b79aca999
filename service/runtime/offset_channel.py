"""Compensation in motion: measurements into the controller, its offsets out to the CNC, every
decision into the log. The controller decides; this module only carries its orders out.

Before each write the CNC's total wear offset is read and checked against the cumulative
limit (``check_before_write``); an offset whose outcome is unknown is settled from the CNC's
registers (acknowledgement, request, total) once they can tell, never re-sent. The log is
written by its own thread: an order to write is committed before the write goes out, the
rest is handed over without waiting.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import logging
import sqlite3
import time
from collections.abc import Awaitable, Callable
from dataclasses import asdict, replace
from typing import Protocol

from calib_store.compensation_log import CompensationLog
from drivers.plc.client import WriteResult
from service.compensation import (
    QUIET_KINDS,
    CncReading,
    CompensationController,
    CompensationSettings,
    Decision,
    Kind,
    MeasurementIn,
    State,
)
from service.compensation.entries import EntryCompensation
from service.compensation.job import JobFeature, OffsetEntry
from service.runtime.listeners import Listeners

log = logging.getLogger("shaftgauge.compensation")

CNC_REFRESH_S = 5.0
"""How often the CNC's registers are read when nothing is in flight (connection state,
total wear offset)."""


Persist = Callable[[], Awaitable[None]]
"""Stores a change before it is applied (raises when it cannot)."""


class LogUnavailableError(RuntimeError):
    """An order to write an offset could not be logged: it must not be carried out."""


class OffsetTransport(Protocol):
    """What the channel needs of the CNC side (``drivers.plc.client.OffsetWriter`` that
    writes to the CNC, ``drivers.plc.pull.PullCnc`` that posts for a CNC that polls, or a
    fake CNC in tests)."""

    async def write_offset(self, offset_mm: float, seq: int) -> WriteResult:
        """Write one offset once; the result says APPLIED, NOT_APPLIED or UNKNOWN."""

    async def read_cnc(self) -> CncReading | None:
        """The CNC's registers, or None when they cannot be read now."""

    # A transport on which the CNC applies an offered offset at most once, however often it
    # is offered, also has ``async resume(seq, offset_mm, base_mm)``: offer it again after a
    # restart (``drivers.plc.pull.PullCnc``; the push writer never re-sends).


class OffsetChannel:
    """Drives one offset entry's controller with its transport (None: nothing is ever
    written), judging each measurement against its feature (``compensation``; None: against
    the controller's own settings, the settings' feature when no job is in force).

    Serialised by an asyncio lock: measurements, write outcomes, settings and people's
    commands are handled one at a time, in order. Every change of the controller goes
    through a method of this class.
    """

    def __init__(self, controller: CompensationController, writer: OffsetTransport | None,
                 store: CompensationLog | None = None,
                 on_decision: Callable[[Decision], None] | None = None,
                 clock: Callable[[], float] = time.monotonic,
                 compensation: EntryCompensation | None = None,
                 entry: OffsetEntry | None = None) -> None:
        self.controller, self.writer, self.store = controller, writer, store
        self.compensation = compensation
        self.entry = entry if entry is not None else (
            compensation.entry if compensation is not None else None)
        self.on_decision = on_decision
        self.clock = clock
        self.last_write: WriteResult | None = None
        self.last_write_s = -float("inf")   # when, on ``clock``
        self.writes: Listeners[WriteResult] = Listeners("offset write")
        self._lock = asyncio.Lock()
        self._last_refresh = -float("inf")

    @property
    def log_problem(self) -> str:
        """Why the decision log cannot be written now (empty: it can)."""
        return self.store.problem if self.store is not None else ""

    def _submit(self, decision: Decision, durable: bool = False
                ) -> concurrent.futures.Future | None:
        assert self.store is not None
        e = self.entry or OffsetEntry(1)
        return self.store.submit(decision.as_dict(), time.time(),
                                 asdict(self.controller.persisted),
                                 quiet=decision.kind in QUIET_KINDS, durable=durable,
                                 tool=e.tool, entry=e.number or 0)

    def _named(self, decision: Decision) -> Decision:
        e = self.entry
        return decision if e is None else replace(decision, tool=e.tool, entry=e.number)

    def _note(self, decision: Decision) -> Decision:
        """Hand a decision to the log (without waiting), the log file and the listeners."""
        decision = self._named(decision)
        if self.store is not None:
            try:
                self._submit(decision)
            except sqlite3.Error as err:  # closed while stopping
                log.warning("decision not logged: %s", err)
        level = logging.WARNING if decision.kind in (Kind.ALARM, Kind.STOPPED, Kind.UNCERTAIN,
                                                     Kind.NOT_APPLIED, Kind.LIMIT) \
            else logging.DEBUG
        log.log(level, "compensation%s %s: %s", "" if self.entry is None else
                f" of {self.entry}", decision.kind.value, decision.reason)
        if self.on_decision is not None:
            self.on_decision(decision)
        return decision

    async def _note_durable(self, decision: Decision) -> Decision:
        """Log a decision and wait until it is committed (LogUnavailableError if it cannot
        be)."""
        decision = self._named(decision)
        if self.store is not None:
            fut = self._submit(decision, durable=True)
            try:
                await asyncio.wrap_future(fut)
            except sqlite3.Error as err:
                raise LogUnavailableError(f"the compensation log cannot be written ({err})"
                                          ) from err
        if self.on_decision is not None:
            self.on_decision(decision)
        return decision

    async def on_measurement(self, m: MeasurementIn, feature: JobFeature | None = None
                             ) -> list[Decision]:
        """Judge a measurement (of ``feature``, one of the entry's; None: a measurement of no
        feature, which the controller refuses or holds); write an offset when the controller
        asks for one."""
        async with self._lock:
            if self.compensation is not None and feature is not None:
                order = self.compensation.on_measurement(m, self.clock(), feature)
            else:
                order = self.controller.on_measurement(m, self.clock())
            if order.kind is not Kind.WRITE:
                return [self._note(order)]
            try:
                await self._note_durable(order)
            except LogUnavailableError as err:  # an offset that cannot be logged is not written
                return [order, self._note(self.controller.on_write_outcome(
                    order.offset_seq, False, self.clock(), f"not written: {err}"))]
            return [order, *await self._write(order)]

    async def _write(self, order: Decision) -> list[Decision]:
        assert order.offset_mm is not None and order.offset_seq is not None
        if self.writer is None:
            return [self._note(self.controller.on_write_outcome(
                order.offset_seq, False, self.clock(), "no CNC connection is configured"))]
        cnc = await self.writer.read_cnc()
        veto = self.controller.check_before_write(
            order.offset_seq, None if cnc is None else cnc.total_mm, self.clock())
        if veto is not None:
            return [self._note(veto)]
        result = await self.writer.write_offset(order.offset_mm, order.offset_seq)
        self.last_write, self.last_write_s = result, self.clock()
        self.writes.tell(result)
        return [self._note(self.controller.on_write_outcome(
            order.offset_seq, result.applied, self.clock(), result.message))]

    async def resume(self) -> None:
        """After a start: offer an offset whose fate was unknown when the gauge stopped
        again, where the transport can (``resume``): the CNC answers it, once."""
        async with self._lock:
            p = self.controller.persisted
            resume = getattr(self.writer, "resume", None)
            if self.controller.state is not State.UNCERTAIN or resume is None \
                    or p.pending_seq is None or p.pending_offset_mm is None \
                    or p.pending_total_before_mm is None:
                return
            await resume(p.pending_seq, p.pending_offset_mm, p.pending_total_before_mm)
            log.info("offset %d (%+.4f mm) offered to the CNC again after a restart",
                     p.pending_seq, p.pending_offset_mm)

    async def settle(self) -> Decision | None:
        """If an offset's fate is unknown, read the CNC's registers and settle it when they
        can tell; otherwise None (nothing is sent meanwhile)."""
        async with self._lock:
            c = self.controller
            if c.state is not State.UNCERTAIN or self.writer is None:
                return None
            cnc = await self.writer.read_cnc()
            if cnc is None:
                return None
            d = c.settle_from_cnc(cnc, self.clock())
            return None if d is None else self._note(d)

    async def refresh(self) -> Decision | None:
        """Read the CNC's registers now: its connection state and total wear offset (taken as
        the baseline of the cumulative limit when there is none)."""
        async with self._lock:
            if self.writer is None:
                return None
            self._last_refresh = self.clock()
            cnc = await self.writer.read_cnc()
            if cnc is None:
                return None
            d = self.controller.observe_cnc_total(cnc.total_mm, self.clock())
            return None if d is None else self._note(d)

    async def tick(self) -> None:
        """One step of settling (``EntryChannels.run_settlers``): settle an unknown offset,
        or read the CNC every ``CNC_REFRESH_S`` (every step while compensation waits for its
        baseline)."""
        try:
            if self.controller.state is State.UNCERTAIN:
                await self.settle()
            elif self._baseline_wanted() or \
                    self.clock() - self._last_refresh >= CNC_REFRESH_S:
                await self.refresh()
        except asyncio.CancelledError:
            raise
        except Exception:  # keep settling: a bug here must not end the task silently
            log.exception("settling an offset failed")

    def _baseline_wanted(self) -> bool:
        """Compensation is on and its reference (or the CNC's total) is not known yet."""
        p = self.controller.persisted
        return p.cnc_total_mm is None or (p.baseline_mm is None
                                          and not self.controller.settings.shadow)

    async def command(self, action: str, who: str = "") -> Decision:
        """A command: ``reset`` (moves the limit's reference to where the CNC's total stands),
        ``insert_change`` (a reset a person recorded for a new insert) or ``acknowledge``."""
        async with self._lock:
            now = self.clock()
            if action in ("reset", "insert_change"):
                d = self.controller.reset(now, who, insert=action == "insert_change")
            elif action == "acknowledge":
                d = self.controller.acknowledge_alarm(now, who)
            else:
                raise ValueError(f"unknown compensation command {action!r}")
            d = self._note(d)
        if d.kind is Kind.RESET:
            await self.refresh()  # the new baseline at once, when the CNC answers
        return d

    async def refuse_reset(self, who: str, why: str) -> Decision:
        """Log a reset that was asked for and not carried out."""
        async with self._lock:
            return self._note(self.controller.refuse_reset(self.clock(), who, why))

    async def update_settings(self, settings: CompensationSettings, who: str,
                              persist: Persist | None = None) -> Decision:
        """New settings (ValueError naming the bad one), in force once ``persist`` has
        stored them (what it raises leaves everything as it was)."""
        async with self._lock:
            self.controller.check_settings(settings)
            if persist is not None:
                await persist()
            return await self._settings_logged(
                self.controller.update_settings(settings, self.clock(), who))

    async def note_settings(self, what: str, who: str, persist: Persist,
                            apply: Callable[[], None]) -> Decision:
        """A setting the controller does not own (the part temperature): ``apply`` once
        ``persist`` has stored it, and log it."""
        async with self._lock:
            await persist()
            apply()
            return await self._settings_logged(
                self.controller.note_settings(what, self.clock(), who))

    async def _settings_logged(self, d: Decision) -> Decision:
        """A settings change is in force whether or not it could be logged (say so)."""
        try:
            return await self._note_durable(d)
        except LogUnavailableError as err:
            log.error("settings changed but not logged: %s", err)
            return d

    def set_calibration(self, calibration_id: int | None) -> None:
        """Measurements from another calibration than this one are refused from now on."""
        self.controller.calibration_id = calibration_id

    def set_writes_blocked(self, why: str) -> None:
        """Offsets are only proposed while ``why`` is not empty (a master check)."""
        self.controller.writes_blocked = why
