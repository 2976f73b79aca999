"""The compensation in the running service: the only owner of the controller (through its
offset channel), its settings and the part temperature (kept across restarts), the offset
hold, and the gate a master check puts on writes. Every change goes through a method here and
runs under the channel's lock."""

from __future__ import annotations

import asyncio
import json
import logging
import sqlite3
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from typing import Any

from calib_store.compensation_log import CompensationLog
from calib_store.store import NotStoredError
from drivers.plc.client import WriteResult
from service.compensation import (
    CompensationController,
    CompensationSettings,
    ControllerState,
    Decision,
    MeasurementIn,
    State,
)
from service.compensation.job import Job, JobFeature
from service.compensation.tools import ToolCompensation
from service.measurement_record import Feature, MeasurementRecord
from service.offset_channel import OffsetChannel, OffsetTransport
from service.runtime.listeners import Listeners
from service.runtime.tool_channels import NO_TOOL_IN_HANDSHAKE, ToolChannels

log = logging.getLogger("shaftgauge.compensation")

RUNTIME_SETTINGS_KEY = "runtime_settings"
QUEUE_SIZE = 256


@dataclass(frozen=True)
class RuntimeSettings:
    """What can be changed while the service runs, as the config file gave it or as last
    changed (compensation tuning and feature, part temperature)."""

    compensation: CompensationSettings
    part_temp_c: float | None
    alpha_per_k: float

    def as_doc(self) -> dict[str, Any]:
        """JSON-ready (compared after a round trip)."""
        return json.loads(json.dumps({"compensation": asdict(self.compensation),
                                      "part_temp_c": self.part_temp_c,
                                      "alpha_per_k": self.alpha_per_k}))


_GRAVITY = (State.ACTIVE, State.PENDING, State.UNCERTAIN, State.ALARM, State.STOPPED)


@dataclass(frozen=True)
class OffsetHold:
    """Measurements do not count for compensation until ``until_s`` (monotonic)."""

    until_s: float
    why: str
    owner: str | None
    code: str


def restored_settings(from_file: RuntimeSettings, log_: CompensationLog | None
                      ) -> RuntimeSettings:
    """The settings to start with: those last changed at run time, unless the config file's
    own have changed since (then the file's, and the log says so)."""
    stored = log_.get_value(RUNTIME_SETTINGS_KEY) if log_ is not None else None
    if stored is None or stored.get("config") != from_file.as_doc():
        if stored is not None:
            log.warning("the config file's compensation or temperature settings changed "
                        "since the last run: they replace the changes made at run time")
        return from_file
    known = CompensationSettings.__dataclass_fields__
    comp = CompensationSettings(**{k: v for k, v in stored["compensation"].items()
                                   if k in known})
    if comp.problems():
        log.error("stored runtime settings are inconsistent (%s): the config file's are used",
                  "; ".join(comp.problems()))
        return from_file
    log.info("compensation settings as last changed at run time (shadow %s)", comp.shadow)
    return RuntimeSettings(comp, stored["part_temp_c"], stored["alpha_per_k"])


class CompensationService:
    """Owns the controller, its settings, the part temperature, the hold and the master gate.

    Parameters
    ----------
    from_file : RuntimeSettings
        The config file's settings (the stored ones win unless these changed since).
    writer : OffsetTransport or None
        The CNC's offset registers (None: nothing is ever written).
    log_ : CompensationLog or None
        Decisions, state and runtime settings.
    reset_command : bool
        Whether a reset from the CNC's command register is carried out.
    store_error : str
        Why there is no log (changes are then refused: they could not be kept).
    tool_transport : callable or None
        Tool number -> its transport, where the handshake names the tool (``PullCnc.tool``,
        ``OffsetWriter.tool`` with ``plc.tool_stride``): a job of several tools then has a
        channel per tool (``ToolChannels``).
    """

    def __init__(self, from_file: RuntimeSettings, writer: OffsetTransport | None,
                 log_: CompensationLog | None, reset_command: bool = False,
                 store_error: str = "",
                 tool_transport: Callable[[int], OffsetTransport] | None = None) -> None:
        self.from_file = from_file
        self.log = log_
        self.store_error = store_error
        self.reset_command = reset_command
        current = restored_settings(from_file, log_)
        self.part_temp_c, self.alpha_per_k = current.part_temp_c, current.alpha_per_k
        state = ControllerState.from_dict(log_.load_state() if log_ else None)
        self.channel = OffsetChannel(CompensationController(current.compensation, state),
                                     writer, log_, on_decision=self._decided)
        self._job: Job | None = None  # the job in force (set_job): tuning is checked against it
        self.tools = ToolChannels(tool_transport, log_, self._decided, blocked=""
                                  if tool_transport is not None or writer is None
                                  else NO_TOOL_IN_HANDSHAKE,
                                  writes=self.channel.writes)
        self._decisions: Listeners[Decision] = Listeners("decision")
        self._settings_changed: Listeners[CompensationSettings] = Listeners("settings change")
        self._hold: OffsetHold | None = None
        self._queue: asyncio.Queue[tuple[MeasurementIn, JobFeature | None]] | None = None
        self.dropped = 0
        self.errors = 0

    # ---- listeners -----------------------------------------------------------------------

    def on_decision(self, listener: Callable[[Decision], None]) -> None:
        """Call ``listener(decision)`` for every decision."""
        self._decisions.add(listener)

    def on_settings(self, listener: Callable[[CompensationSettings], None]) -> None:
        """Call ``listener(settings)`` when the settings change (and once now)."""
        self._settings_changed.add(listener)
        listener(self.settings)

    def _decided(self, d: Decision) -> None:
        self._decisions.tell(d)

    # ---- read-only views -----------------------------------------------------------------

    @property
    def controller(self) -> CompensationController:
        """The controller (read it; change it through this service)."""
        return self.channel.controller

    @property
    def settings(self) -> CompensationSettings:
        """The compensation settings in force."""
        return self.channel.controller.settings

    @property
    def state(self) -> State:
        """The gravest state of the channels in force (a stopped tool is the gauge's stop;
        the one channel no tool of the job uses does not count)."""
        return max((ch.controller.state for _, ch in self.in_force()), key=_GRAVITY.index)

    def in_force(self) -> list[tuple[int | None, OffsetChannel]]:
        """The offsets' channels of the job in force by tool, for every reader: each tool's
        in a job of several, else the one channel (with its tool's number, None without a
        job)."""
        if self.tools.channels:
            return sorted(self.tools.channels.items())
        tools = self._job.tool_numbers() if self._job is not None else ()
        return [(tools[0] if len(tools) == 1 else None, self.channel)]

    def last_write(self) -> WriteResult | None:
        """The latest offset write of any channel in force."""
        written = [ch for _, ch in self.in_force() if ch.last_write is not None]
        return max(written, key=lambda ch: ch.last_write_s).last_write if written else None

    def on_write(self, listener: Callable[[WriteResult], None]) -> None:
        """Call ``listener(result)`` after every offset write, of any channel."""
        self.channel.writes.add(listener)  # the tools' channels share them

    def feature(self) -> Feature:
        """Nominal and tolerance in force."""
        s = self.settings
        return Feature(s.nominal_mm, s.tol_lower_mm, s.tol_upper_mm)

    def offset_hold(self) -> str | None:
        """Why offsets are held now, or None."""
        h = self._hold
        return h.why if h is not None and time.monotonic() < h.until_s else None

    def status(self) -> dict[str, Any]:
        """The compensation's part of the service status: the one channel's offsets, or
        (a job of several tools) each tool's under ``tools`` and none at the top."""
        c = self.channel.controller
        p = c.persisted
        one = not self.tools.channels
        return {"state": self.state.value, "shadow": c.settings.shadow,
                **{k: v if one else None for k, v in (
                    ("cumulative_offset_mm", c.cumulative_mm), ("cnc_total_mm", p.cnc_total_mm),
                    ("baseline_mm", p.baseline_mm),
                    ("cnc_offset_from_baseline_mm", p.cnc_offset_mm()),
                    ("offset_seq", p.offset_seq), ("pending_seq", p.pending_seq))},
                "max_total_mm": c.settings.max_total_mm, "held": self.offset_hold(),
                "log_rows": None if self.log is None else self.log.rows_written,
                "tools": self.tools.status()}

    # ---- the measurements ----------------------------------------------------------------

    @staticmethod
    def cannot_take(job: Job) -> str:
        """Why the running service cannot correct ``job`` ("" when it can): a feature on an
        offset entry other than its tool's own needs a handshake that names the entry, which
        the CNC links do not have yet (the controllers do: ``JobCompensation``)."""
        for i, f in enumerate(job.features):
            if f.entry is not None:
                return (f"features[{i}].entry: offset entries other than a tool's own are not "
                        "carried by the CNC handshake yet; leave it out (the tool's own "
                        "entry)")
        return ""

    def set_job(self, job: Job | None) -> None:
        """The job in force: one whose features one tool finishes has each measurement
        judged against its feature and taken into the tool's law (``ToolCompensation``); one
        of several tools, a channel per tool (``ToolChannels``); otherwise the settings'
        single feature, as before."""
        why = self.cannot_take(job) if job is not None else ""
        if why:
            raise ValueError(why)
        tools = job.tool_numbers() if job is not None else ()
        self.tools.set_job(job, self.settings, self.channel.controller.calibration_id)
        self._job = job
        if job is None or len(job.features) < 2 or len(tools) != 1:
            self.channel.tool = None
            return
        self.channel.tool = ToolCompensation(job, tools[0], self.settings,
                                             controller=self.channel.controller)

    def submit(self, record: MeasurementRecord, received_s: float, held: str | None = None,
               feature: JobFeature | None = None) -> None:
        """Queue a published measurement (of ``feature`` of the job) for the controller (the
        oldest is dropped and counted when the queue is full). Held measurements go in with a
        held status: while offsets are held, or when ``held`` names why this one may not move
        the tool (``held_for_<held>``)."""
        if self._queue is None:
            return
        if self._queue.full():
            self._queue.get_nowait()
            self.dropped += 1
        hold = self._hold.code if self.offset_hold() and self._hold else held
        if self.channel.log_problem:  # an offset that cannot be logged is not written, nor
            hold = "log_unwritable"   # proposed anew with each measurement meanwhile
        self._queue.put_nowait((MeasurementIn(
            record.seq, received_s, ("held_for_" + hold) if hold else record.status,
            record.compensation_diameter_mm, record.uncertainty_mm, record.calibration_id),
            feature))

    async def run(self) -> None:
        """Judge queued measurements until cancelled."""
        self._queue = asyncio.Queue(QUEUE_SIZE)
        while True:
            m, feature = await self._queue.get()
            try:
                if feature is None or not await self.tools.judge(m, feature):
                    await self.channel.on_measurement(m, feature)
            except asyncio.CancelledError:
                raise
            except Exception:
                self.errors += 1
                log.exception("compensation error")

    async def follow_master_gate(self, blocking: Callable[[], str | None],
                                 period_s: float = 0.2) -> None:
        """Only propose offsets while ``blocking()`` says why (a failed or overdue master
        check); runs until cancelled."""
        while True:
            self.set_writes_blocked(blocking() or "")
            await asyncio.sleep(period_s)

    # ---- changes -------------------------------------------------------------------------

    def hold_offsets(self, seconds: float, why: str, owner: str | None = None,
                     code: str = "calibration") -> None:
        """Treat every measurement as doubtful for ``seconds`` from now (the camera is
        looking at a calibration board, or at the master): nothing is written to the CNC
        meanwhile. ``owner`` may end it early with ``release_hold``; ``code`` names it in the
        decision log (``held_for_<code>``)."""
        self._hold = OffsetHold(time.monotonic() + seconds, why, owner, code)
        log.info("offsets held for %.0f s: %s", seconds, why)

    def release_hold(self, owner: str) -> bool:
        """End the hold if ``owner`` set it; True when a hold ended."""
        if self.offset_hold() is None or self._hold is None or self._hold.owner != owner:
            return False
        log.info("offsets no longer held (were: %s)", self._hold.why)
        self._hold = None
        return True

    def set_calibration(self, calibration_id: int) -> None:
        """Only measurements made with this calibration count from now on."""
        self.channel.set_calibration(calibration_id)
        self.tools.set_calibration(calibration_id)

    def set_writes_blocked(self, why: str) -> None:
        """Offsets are only proposed while ``why`` is not empty (a master check)."""
        self.channel.set_writes_blocked(why)
        self.tools.set_writes_blocked(why)

    async def update_settings(self, settings: CompensationSettings, who: str) -> Decision:
        """New compensation settings (ValueError naming the bad one), stored before they are
        in force (NotStoredError, nothing changed, when they cannot be), and logged with who
        changed what. Tuning that a feature of the stored job in force could not hold (a null
        band wider than its tolerance) is refused naming the feature: the job is checked with
        the same rules when it is stored."""
        job = self._job
        problems = job.tuning_problems(settings) if job is not None and not job.is_single \
            else []
        if problems:
            raise ValueError("; ".join(problems))
        d = await self.channel.update_settings(settings, who, lambda: self._save(RuntimeSettings(
            settings, self.part_temp_c, self.alpha_per_k)))
        if self.channel.tool is not None:
            self.channel.tool.rebase(settings)
        await self.tools.update_settings(settings, who)
        self._settings_changed.tell(settings)
        return d

    async def update_feature(self, who: str, **changes: float | None) -> Decision:
        """Change some of nominal and tolerances (ValueError while inconsistent)."""
        return await self.update_settings(replace(self.settings, **changes), who)

    async def set_temperature(self, part_temp_c: float | None, alpha_per_k: float | None,
                              who: str) -> None:
        """The part temperature (and expansion coefficient) for the diameter at 20 C; stored
        before it is in force (NotStoredError when it cannot be) and logged."""
        alpha = self.alpha_per_k if alpha_per_k is None else alpha_per_k

        def apply() -> None:
            self.part_temp_c, self.alpha_per_k = part_temp_c, alpha

        await self.channel.note_settings(
            f"temperature changed (part_temp_c={part_temp_c!r}, alpha_per_k={alpha!r})", who,
            lambda: self._save(RuntimeSettings(self.settings, part_temp_c, alpha)), apply)

    async def reset(self, source: str, who: str, tool: int | None = None) -> Decision:
        """Reset compensation: ``tool``'s of a job of several tools, or (None) the single
        channel's and every tool's. From the CNC's command register (``source`` "modbus")
        it is refused and logged unless ``reset_command`` allows it; a reset moves the
        reference of the cumulative limit to where the CNC's total stands. KeyError when
        ``tool`` has no compensation of its own."""
        if source == "modbus" and not self.reset_command:
            return await self.channel.refuse_reset(
                who, "resets from the CNC's command register are off (modbus.reset_command); "
                "a technician resets over the API")
        return await self._command("reset", who, tool)

    async def acknowledge(self, who: str, tool: int | None = None) -> Decision:
        """Acknowledge an out-of-tolerance alarm (``tool``'s, or every one's)."""
        return await self._command("acknowledge", who, tool)

    async def _command(self, action: str, who: str, tool: int | None) -> Decision:
        if tool is not None:
            return (await self.tools.command(action, who, tool))[0]
        d = await self.channel.command(action, who)
        await self.tools.command(action, who)
        return d

    async def _save(self, settings: RuntimeSettings) -> None:
        """Store ``settings`` as the runtime settings (NotStoredError when they cannot be)."""
        if self.log is None:
            raise NotStoredError(f"not stored, nothing changed: the store cannot be used "
                                 f"({self.store_error})")
        doc = settings.as_doc()
        doc["config"] = self.from_file.as_doc()
        try:
            await asyncio.wrap_future(self.log.submit_value(RUNTIME_SETTINGS_KEY, doc,
                                                              retry=False))
        except sqlite3.Error as err:
            log.error("runtime settings not stored, nothing changed: %s", err)
            raise NotStoredError(f"not stored, nothing changed: the store cannot be written "
                                 f"({err})") from err
