"""Compensation in motion: measurements into the controller, its offsets out to the CNC, every
decision into the log. The controller decides; this module only carries its orders out."""

from __future__ import annotations

import asyncio
import logging
import sqlite3
import time
from collections.abc import Callable

from calib_store.compensation_log import CompensationLog
from drivers.plc.client import OffsetWriter, WriteResult
from service.compensation import CompensationController, Decision, Kind, MeasurementIn, State

log = logging.getLogger("shaftgauge.compensation")


class LogUnavailableError(RuntimeError):
    """An order to write an offset could not be logged: it must not be carried out."""


class OffsetChannel:
    """Drives one controller with one offset writer (None: nothing is ever written).

    Serialised by an asyncio lock: measurements, write outcomes and person's commands are
    handled one at a time, in order.
    """

    def __init__(self, controller: CompensationController, writer: OffsetWriter | None,
                 store: CompensationLog | None = None,
                 on_decision: Callable[[Decision], None] | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.controller, self.writer, self.store = controller, writer, store
        self.on_decision = on_decision
        self.clock = clock
        self.last_write: WriteResult | None = None
        self.log_problem = ""   # why the decision log cannot be written now (empty: it can)
        self._lock = asyncio.Lock()

    def _record(self, decision: Decision) -> Decision:
        if self.store is not None:
            try:
                self.store.record(decision, time.time(), self.controller.persisted)
                self.log_problem = ""
            except sqlite3.Error as err:  # a full disk, a damaged file: say so, keep going
                if not self.log_problem:
                    log.error("the compensation log cannot be written: %s", err)
                self.log_problem = f"the compensation log cannot be written ({err})"
                if decision.kind is Kind.WRITE:
                    raise LogUnavailableError(self.log_problem) from err
        level = logging.WARNING if decision.kind in (Kind.ALARM, Kind.STOPPED, Kind.UNCERTAIN,
                                                     Kind.NOT_APPLIED, Kind.LIMIT) \
            else logging.DEBUG
        log.log(level, "compensation %s: %s", decision.kind.value, decision.reason)
        if self.on_decision is not None:
            self.on_decision(decision)
        return decision

    async def on_measurement(self, m: MeasurementIn) -> list[Decision]:
        """Judge a measurement; write an offset when the controller asks for one."""
        async with self._lock:
            order = self.controller.on_measurement(m, self.clock())
            try:
                out = [self._record(order)]
            except LogUnavailableError as err:  # an offset that cannot be logged is not written
                return [self._record(self.controller.on_write_outcome(
                    order.offset_seq, False, self.clock(), f"not written: {err}"))]
            if out[0].kind is Kind.WRITE:
                out.append(await self._write(out[0]))
            return out

    async def _write(self, order: Decision) -> Decision:
        assert order.offset_mm is not None and order.offset_seq is not None
        if self.writer is None:
            return self._record(self.controller.on_write_outcome(
                order.offset_seq, False, self.clock(), "no CNC connection is configured"))
        result = await self.writer.write_offset(order.offset_mm, order.offset_seq)
        self.last_write = result
        return self._record(self.controller.on_write_outcome(
            order.offset_seq, result.applied, self.clock(), result.message))

    async def settle(self) -> Decision | None:
        """If an offset's fate is unknown, read the CNC's acknowledgement and settle it.

        The CNC echoes the sequence of the last offset it applied; offsets are never re-sent,
        so the pending one was applied exactly when the echo equals its sequence.
        """
        async with self._lock:
            c = self.controller
            if c.state is not State.UNCERTAIN or self.writer is None:
                return None
            seq = c.persisted.pending_seq
            ack = await self.writer.read_ack()
            if ack is None or seq is None:
                return None
            return self._record(c.reconcile(seq, ack == seq, self.clock()))

    async def run_settler(self, period_s: float = 1.0) -> None:
        """Settle unknown offsets as soon as the CNC answers again; runs until cancelled."""
        while True:
            await asyncio.sleep(period_s)
            try:
                await self.settle()
            except Exception:  # keep settling: a bug here must not end the task silently
                log.exception("settling an offset failed")

    async def command(self, action: str) -> Decision:
        """A person's command: ``reset`` or ``acknowledge``."""
        async with self._lock:
            now = self.clock()
            if action == "reset":
                d = self.controller.reset(now)
            elif action == "acknowledge":
                d = self.controller.acknowledge_alarm(now)
            else:
                raise ValueError(f"unknown compensation command {action!r}")
            return self._record(d)
