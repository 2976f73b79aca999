"""The registers the CNC polls, as the running service fills them: the bank and its server,
the CNC's writes (commands, feature) handed to their owner, and the status and fault bits
from a pure function of a snapshot (``status_words``, tested bit by bit)."""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, replace

from calib_store.store import NotStoredError
from drivers.plc.registers import (
    TOOL_BLOCKS,
    Command,
    FaultBit,
    RegisterBank,
    StatusBit,
    mm_to_units,
    units_to_mm,
)
from drivers.plc.server import GaugeModbusServer, ModbusAccess, run_heartbeat
from drivers.plc.tls import TlsFiles
from service.compensation import CompensationSettings, Decision, State
from service.compensation.job import JobError, job_from_doc
from service.config import ModbusSettings
from service.measurement_record import MeasurementRecord
from service.runtime.compensating import CompensationService
from service.runtime.job_service import JobService

log = logging.getLogger("shaftgauge.modbus")

REFRESH_S = 0.2
_FEATURE = {"nominal": "nominal_mm", "tol_upper": "tol_upper_mm", "tol_lower": "tol_lower_mm"}


@dataclass(frozen=True)
class StatusSnapshot:
    """What the status and fault bits are made of, read at one moment."""

    healthy: bool = False
    camera_streaming: bool = False
    calibrated: bool = False
    latest_status: str | None = None      # None: nothing measured yet
    latest_in_tolerance: bool | None = None
    age_s: float | None = None            # of the latest measurement
    max_age_s: float = 5.0
    shadow: bool = True
    compensation: State = State.ACTIVE
    plc_configured: bool = False
    plc_connected: bool = False
    plc_outage: bool = False
    writes_blocked: bool = False
    rule_violation: bool = False          # SPC: a run rule fired at the latest subgroup
    study_failed: bool = False            # the type-1 gauge study failed or is overdue
    not_concentric: bool = False          # refused: off the spindle axis, no angle known
    tir_mm: float | None = None           # the run-out, when known
    runout_phase_deg: float | None = None
    max_tir_mm: float = 0.02
    ront_mm: float | None = None          # the roundness, when known
    lobes: int = 0


def status_words(s: StatusSnapshot) -> tuple[StatusBit, FaultBit, int]:
    """The ``status`` and ``faults`` registers and ``measurement_age`` (ms, 65535 when
    older or none) for a snapshot."""
    status, faults = StatusBit(0), FaultBit(0)
    if s.healthy:
        status |= StatusBit.HEALTHY
    if s.camera_streaming:
        status |= StatusBit.CAMERA_STREAMING
    else:
        faults |= FaultBit.CAMERA_LOST
    fresh = s.age_s is not None and s.age_s <= s.max_age_s
    if s.latest_status == "ok" and fresh:
        status |= StatusBit.MEASUREMENT_VALID
        if s.latest_in_tolerance:
            status |= StatusBit.IN_TOLERANCE
    elif s.latest_status is not None and s.latest_status != "ok":
        faults |= FaultBit.NO_MEASUREMENT
    if s.latest_status is not None and not fresh:
        faults |= FaultBit.STALE_MEASUREMENT
    if s.shadow:
        status |= StatusBit.SHADOW_MODE
    elif s.compensation in (State.ACTIVE, State.PENDING):
        status |= StatusBit.COMPENSATION_ACTIVE
    # The part just measured is out (flagged: the tool is still corrected), or a deviation
    # beyond the plausibility limit holds compensation with an alarm.
    if s.compensation is State.ALARM or (fresh and s.latest_status == "ok"
                                         and s.latest_in_tolerance is False):
        faults |= FaultBit.OUT_OF_TOLERANCE
    if s.compensation is State.STOPPED:
        faults |= FaultBit.SAFE_AREA_STOP
    if s.plc_configured:
        if s.plc_connected:
            status |= StatusBit.PLC_CONNECTED
        elif s.plc_outage:
            faults |= FaultBit.OFFSET_WRITE_FAILED
    if s.compensation is State.UNCERTAIN:  # an offset the CNC has not settled: nothing moves
        faults |= FaultBit.OFFSET_WRITE_FAILED
    if s.calibrated:
        status |= StatusBit.CALIBRATED
    else:
        faults |= FaultBit.NO_CALIBRATION
    if s.writes_blocked:
        faults |= FaultBit.MASTER_CHECK_DUE
    if s.rule_violation:
        status |= StatusBit.RULE_VIOLATION
    if s.study_failed:
        faults |= FaultBit.GAUGE_STUDY_FAILED
    if s.tir_mm is not None:
        status |= StatusBit.RUNOUT_KNOWN
        if s.tir_mm > s.max_tir_mm:
            faults |= FaultBit.RUNOUT_BEYOND_LIMIT
    if s.not_concentric:
        faults |= FaultBit.NOT_CONCENTRIC
    age_ms = 65535 if s.age_s is None else min(65535, int(s.age_s * 1000))
    return status, faults, age_ms


def form_words(s: StatusSnapshot) -> dict[str, int]:
    """The form and position registers for a snapshot (no value while not known)."""
    phase = s.runout_phase_deg
    return {"runout_tir": mm_to_units(s.tir_mm), "ront": mm_to_units(s.ront_mm),
            "runout_phase": 0xFFFF if phase is None or s.tir_mm is None
            else round(phase % 360.0 * 100.0) % 36000, "lobes": max(0, min(s.lobes, 0xFFFF))}


class ModbusFacade:
    """Owns the register bank and the Modbus server the CNC polls.

    Parameters
    ----------
    settings : ModbusSettings
        Where to serve, unit id, word order.
    compensation : CompensationService
        Where the CNC's commands and feature go.
    trigger : callable
        ``trigger()``: the camera takes a frame now (the measure-now command).
    bank : RegisterBank, optional
        The registers, when made beforehand (the pull handshake's transport shares them).
    """

    def __init__(self, settings: ModbusSettings, compensation: CompensationService,
                 trigger: Callable[[], None], bank: RegisterBank | None = None) -> None:
        self.settings = settings
        self.compensation = compensation
        self.trigger = trigger
        self.bank = bank if bank is not None else RegisterBank(settings.word_order)
        self.server = GaugeModbusServer(
            self.bank, settings.host, settings.port, settings.unit_id, on_write=self._on_write,
            check=self._check_write, access=ModbusAccess.of(
                settings.allowed_clients, settings.writers, settings.max_connections),
            tls=TlsFiles(settings.tls.certfile, settings.tls.keyfile, settings.tls.cafile)
            if settings.tls else None)
        self._tasks: set[asyncio.Task] = set()
        self.jobs: JobService | None = None
        self._proposed: dict[int | None, int] = {}   # by tool (None: the one channel), units

    @property
    def port(self) -> int:
        """The port served (the bound one once started)."""
        return self.server.port

    async def start(self, snapshot: Callable[[], StatusSnapshot],
                    healthy: Callable[[], bool]) -> list[asyncio.Task]:
        """Serve (when enabled); returns the background tasks: the heartbeat (counting while
        ``healthy()``) and the status registers (from ``snapshot()`` every ``REFRESH_S``)."""
        if self.settings.enabled:
            try:
                await self.server.start()
            except (OSError, RuntimeError) as err:  # pymodbus: "Could not start listen"
                raise RuntimeError(f"the Modbus server cannot listen on "
                                   f"{self.settings.host}:{self.settings.port} (modbus.port: "
                                   f"is another program using it?): {err}") from err
        loop = asyncio.get_running_loop()
        return [loop.create_task(run_heartbeat(self.bank, healthy), name="heartbeat"),
                loop.create_task(self._refresh(snapshot), name="registers")]

    async def stop(self) -> None:
        """Stop serving."""
        await self.server.stop()

    # ---- what goes in ------------------------------------------------------------------

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
        self.bank.set_many(update)

    def set_feature(self, settings: CompensationSettings) -> None:
        """Nominal and tolerances as in force."""
        self.bank.set_many({"nominal": mm_to_units(settings.nominal_mm),
                            "tol_upper": mm_to_units(settings.tol_upper_mm),
                            "tol_lower": mm_to_units(settings.tol_lower_mm)})

    async def _refresh(self, snapshot: Callable[[], StatusSnapshot]) -> None:
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

    # ---- what the CNC writes -----------------------------------------------------------

    def _feature_changes(self, entries: list[tuple[str, int]]) -> dict[str, float | None]:
        return {_FEATURE[name]: units_to_mm(value) for name, value in entries
                if name in _FEATURE}

    def serve_jobs(self, jobs: JobService) -> None:
        """Serve the job registers (map v4) from ``jobs`` (told of each change:
        ``job_changed``), and take the CNC's writes there."""
        self.jobs = jobs
        self.job_changed()

    def job_changed(self) -> None:
        """The job in force or the feature named changed: its registers and tool blocks."""
        self._show_offsets()  # the job's tools, each in its block
        jobs = self.jobs
        if jobs is not None:
            self.bank.set_many({"job": 0 if jobs.stored is None else jobs.stored.id & 0xFFFF,
                                "feature": jobs.selected or 0})

    def _check_jobs(self, entries: list[tuple[str, int]]) -> str:
        """Why the job, feature or tool written cannot be taken ("" when it can)."""
        values = dict(entries)
        if self.jobs is None or not {"job", "feature", "cnc_tool"} & values.keys():
            return ""
        job = self.jobs.job
        if values.get("job"):
            if self.jobs.store is None:
                return f"job: the store cannot be used ({self.jobs.store_error})"
            try:
                job = job_from_doc(self.jobs.store.get(values["job"]).document)
            except KeyError:
                return f"job: no stored job {values['job']}"
            except JobError as err:
                return f"job {values['job']}: {err}"
        if values.get("feature"):
            if job is None:
                return "feature: no job is in force"
            try:
                job.feature(values["feature"])
            except KeyError as err:
                return f"feature: {err.args[0]}"
        tool = values.get("cnc_tool")
        # The settings' single feature has whatever tool the CNC compensates.
        if tool and self.jobs.stored is not None and (job is None
                                                      or tool not in job.tool_numbers()):
            return (f"cnc_tool: tool {tool} is not in "
                    + ("any job: none is in force" if job is None else
                       f"job {job.part_number!r} (its tools: "
                       f"{', '.join(str(t) for t in job.tool_numbers())})"))
        return ""

    def _check_write(self, entries: list[tuple[str, int]]) -> str:
        """Why a write cannot be taken ("" when it can): a command the settings keep from the
        CNC, a job or feature the gauge does not have, or a feature that does not hold
        together. A write is taken whole or not at all,
        so a refused one leaves ``command`` and ``last_command`` as they were."""
        for name, value in entries:
            if name != "command":
                continue
            if value == Command.RESET_COMPENSATION and not self.compensation.reset_command:
                return ("command 2 (reset) from the CNC is off (modbus.reset_command): a "
                        "technician resets over the API")
            if value == Command.ACKNOWLEDGE_ALARM and not self.settings.acknowledge_command:
                return ("command 3 (acknowledge) from the CNC is off "
                        "(modbus.acknowledge_command): a technician acknowledges over the API")
        problem = self._check_jobs(entries)
        if problem:
            return problem
        changes = self._feature_changes(entries)
        if not changes:
            return ""
        if self.compensation.log is None:
            return f"the store cannot be used ({self.compensation.store_error})"
        try:
            problems = replace(self.compensation.settings, **changes).problems()
        except (TypeError, ValueError) as err:
            return str(err)
        return "; ".join(problems)

    def _on_write(self, entries: list[tuple[str, int]], peer: str) -> None:
        """A CNC wrote registers, the whole write at once (called inside the Modbus server, on
        the event loop)."""
        who = f"modbus:{peer}" if peer else "modbus"
        changes = self._feature_changes(entries)
        if changes:
            self._spawn(self._feature_from_cnc(changes, who))
        values = dict(entries)
        if "part_counter" in values and self.jobs is not None:
            self.jobs.part_counter = values["part_counter"] or None
        if "job" in values or "feature" in values:
            self._spawn(self._job_from_cnc(values.get("job"), values.get("feature"), who))
        for name, value in entries:
            if name == "command":
                self._spawn(self.run_command(Command(value), source="modbus", who=who))

    def _spawn(self, coro: Awaitable[object]) -> None:
        task = asyncio.get_running_loop().create_task(coro)  # type: ignore[arg-type]
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    async def _feature_from_cnc(self, changes: dict[str, float | None], who: str) -> None:
        try:
            await self.compensation.update_feature(who, **changes)
        except (ValueError, NotStoredError) as err:  # changed meanwhile, or not storable
            log.warning("feature from %s not taken: %s", who, err)
            self.set_feature(self.compensation.settings)  # the registers show what is in force

    async def _job_from_cnc(self, job_id: int | None, feature: int | None, who: str) -> None:
        """The job, then the feature, the CNC wrote (checked before the write was taken)."""
        jobs = self.jobs
        assert jobs is not None
        try:
            if job_id == 0:
                jobs.deactivate(who)
            elif job_id is not None:
                await jobs.activate(job_id, who)
            if feature is not None:
                jobs.select(feature or None)
        except (KeyError, ValueError, NotStoredError) as err:  # changed meanwhile
            log.warning("job or feature from %s not taken: %s", who, err)
            self.job_changed()  # the registers show what is in force

    async def run_command(self, command: Command, source: str,
                          who: str | None = None) -> Decision | None:
        """Carry out a command (from the CNC or the API) and acknowledge it in the
        registers."""
        decision = None
        who = who or source
        if command is Command.RESET_COMPENSATION:
            decision = await self.compensation.reset(source, who)
        elif command is Command.ACKNOWLEDGE_ALARM:
            if source == "modbus" and not self.settings.acknowledge_command:
                log.warning("alarm acknowledgement from %s refused: acknowledgements from the "
                            "CNC's command register are off (modbus.acknowledge_command); a "
                            "technician acknowledges over the API", who)
            else:
                decision = await self.compensation.acknowledge(who)
        elif command is Command.MEASURE_NOW:
            with contextlib.suppress(Exception):  # a free-running camera measures anyway
                self.trigger()
        seq = (self.bank.get("command_seq") + 1) & 0xFFFF
        self.bank.set_many({"command": 0, "last_command": int(command), "command_seq": seq})
        log.info("command %s from %s", command.name.lower(), who)
        return decision
