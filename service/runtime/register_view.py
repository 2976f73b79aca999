"""What the registers show the CNC: the latest measurement, the offsets of the job's tools,
the feature and the job in force, and the status and fault bits from a snapshot every
``REFRESH_S`` (the pure ``service.runtime.status_words``)."""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable

from drivers.plc.registers import TOOL_BLOCKS, FaultBit, RegisterBank, mm_to_units
from service.compensation import CompensationSettings, Decision
from service.measurement_record import MeasurementRecord
from service.runtime.compensating import CompensationService
from service.runtime.job_service import JobService
from service.runtime.status_words import StatusSnapshot, form_words, status_words

log = logging.getLogger("shaftgauge.modbus")

REFRESH_S = 0.2


class RegisterView:
    """The only writer of what the gauge shows in the register bank (the CNC's own writes
    and the pull handshake's request block aside).

    Parameters
    ----------
    bank : RegisterBank
        The registers the Modbus server serves.
    compensation : CompensationService
        Whose channels in force each tool's block shows.
    """

    def __init__(self, bank: RegisterBank, compensation: CompensationService) -> None:
        self.bank, self.compensation = bank, compensation
        self.jobs: JobService | None = None
        self._proposed: dict[int | None, int] = {}   # by tool (None: the one channel), units
        self._offsets_shown: dict[str, int] = {}     # what the offsets' registers hold

    def publish(self, record: MeasurementRecord) -> None:
        """The latest measurement."""
        self.bank.set_many({"diameter": mm_to_units(record.diameter_mm),
                            "uncertainty": mm_to_units(record.uncertainty_mm),
                            "measurement_seq": record.seq & 0xFFFFFFFF,
                            "measurement_age": 0})

    def set_sequence(self, seq: int) -> None:
        """The sequence number before any measurement (it never goes back)."""
        self.bank.set("measurement_seq", seq & 0xFFFFFFFF)

    def decided(self, d: Decision) -> None:
        """A compensation decision: the offsets' registers."""
        if d.offset_mm is not None:
            self._proposed[d.tool] = mm_to_units(d.offset_mm)
        self._show_offsets()

    def _show_offsets(self) -> None:
        """Each tool's block from the channels in force (map v5); the gauge-wide registers
        from the one channel, or *no value* in a job of several tools."""
        in_force = self.compensation.in_force()
        one = self.compensation.channel.controller
        several = len(in_force) > 1
        update = {"cumulative_offset": mm_to_units(None if several else one.cumulative_mm),
                  "offset_seq": one.persisted.offset_seq & 0xFFFFFFFF,
                  "proposed_offset": mm_to_units(None) if several else
                  self._proposed.get(None, mm_to_units(None))}
        for k in range(1, TOOL_BLOCKS + 1):
            tool, ch = in_force[k - 1] if k <= len(in_force) else (None, None)
            c = ch.controller if ch is not None else None
            update.update({
                f"tool{k}_number": tool or 0,
                f"tool{k}_proposed": self._proposed.get(ch.tool_number, mm_to_units(None))
                if ch is not None else mm_to_units(None),
                f"tool{k}_offset_seq": c.persisted.offset_seq & 0xFFFFFFFF if c else 0,
                f"tool{k}_cumulative": mm_to_units(c.cumulative_mm if c else None)})
        # Every measurement's decision comes here: write only what changed.
        changed = {k: v for k, v in update.items() if self._offsets_shown.get(k) != v}
        if changed:
            self.bank.set_many(changed)
            self._offsets_shown.update(changed)

    def set_feature(self, settings: CompensationSettings) -> None:
        """Nominal and tolerances as in force."""
        self.bank.set_many({"nominal": mm_to_units(settings.nominal_mm),
                            "tol_upper": mm_to_units(settings.tol_upper_mm),
                            "tol_lower": mm_to_units(settings.tol_lower_mm)})

    def command_done(self, command: int) -> None:
        """A command carried out: ``command`` cleared, ``last_command`` it, ``command_seq``
        counted on."""
        seq = (self.bank.get("command_seq") + 1) & 0xFFFF
        self.bank.set_many({"command": 0, "last_command": int(command), "command_seq": seq})

    def show_jobs(self, jobs: JobService) -> None:
        """Show the job registers (map v4) from ``jobs`` (told of each change:
        ``job_changed``)."""
        self.jobs = jobs
        self.job_changed()

    def job_changed(self) -> None:
        """The job in force or the feature named changed: its registers and tool blocks."""
        self._show_offsets()  # the job's tools, each in its block
        jobs = self.jobs
        if jobs is not None:
            self.bank.set_many({"job": 0 if jobs.stored is None else jobs.stored.id & 0xFFFF,
                                "feature": jobs.selected or 0})

    async def refresh(self, snapshot: Callable[[], StatusSnapshot]) -> None:
        """Status, faults and form from ``snapshot()`` every ``REFRESH_S``, until cancelled."""
        while True:
            await asyncio.sleep(REFRESH_S)
            try:
                snap = snapshot()
                status, faults, age_ms = status_words(snap)
            except Exception:  # keep the loop: a bug here must not freeze the registers
                log.exception("status registers")
                continue
            update = {"status": int(status), "faults": int(faults), "measurement_age": age_ms,
                      **form_words(snap)}
            if faults & FaultBit.STALE_MEASUREMENT:  # a stale diameter is no diameter
                update["diameter"] = mm_to_units(None)
            self.bank.set_many(update)
