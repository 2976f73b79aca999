"""The compensation in the running service: the only owner of its settings and the part
temperature (kept across restarts), of the offsets' channels of the job in force (one for
each offset entry, ``EntryChannels``), the offset hold, and the gate a master check puts on
writes. Every change goes through a method here and runs under the channels' locks."""

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
    CompensationSettings,
    Decision,
    MeasurementIn,
    State,
)
from service.compensation.job import Job, JobFeature, OffsetEntry
from service.compensation.segments import SegmentFusion
from service.measurement_record import Feature, MeasurementRecord
from service.runtime.entry_channels import (
    SETTINGS_ENTRY,
    EntryChannels,
    Transports,
    own_settings,
)
from service.runtime.listeners import Listeners
from service.runtime.offset_channel import OffsetChannel

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
    """Owns the settings, the offsets' channels of the job in force (``EntryChannels``), the
    part temperature, the hold and the master gate.

    Parameters
    ----------
    from_file : RuntimeSettings
        The config file's settings (the stored ones win unless these changed since).
    transport : callable or None
        Offset entry -> its transport (``PullCnc.entry``, ``OffsetWriter.offset``; None:
        nothing is ever written).
    log_ : CompensationLog or None
        Decisions, each entry's state and the runtime settings.
    reset_command : bool
        Whether a reset from the CNC's command register is carried out.
    store_error : str
        Why there is no log (changes are then refused: they could not be kept).
    """

    def __init__(self, from_file: RuntimeSettings, transport: Transports | None,
                 log_: CompensationLog | None, reset_command: bool = False,
                 store_error: str = "") -> None:
        self.from_file = from_file
        self.log = log_
        self.store_error = store_error
        self.reset_command = reset_command
        current = restored_settings(from_file, log_)
        self._settings = current.compensation
        self.part_temp_c, self.alpha_per_k = current.part_temp_c, current.alpha_per_k
        self._decisions: Listeners[Decision] = Listeners("decision")
        self._settings_changed: Listeners[CompensationSettings] = Listeners("settings change")
        self.entries = EntryChannels(transport, log_, self._decided,
                                     writes=Listeners("offset write"))
        self._calibration_id: int | None = None
        self.entries.set_job(None, self._settings, None)
        self._hold: OffsetHold | None = None
        self._queue: asyncio.Queue[tuple[MeasurementIn, JobFeature | None]] | None = None
        self._segments: SegmentFusion[JobFeature] = SegmentFusion()
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

    def on_write(self, listener: Callable[[WriteResult], None]) -> None:
        """Call ``listener(result)`` after every offset write, of any entry."""
        self.entries.writes.add(listener)

    def _decided(self, d: Decision) -> None:
        self._decisions.tell(d)

    # ---- read-only views -----------------------------------------------------------------

    @property
    def settings(self) -> CompensationSettings:
        """The compensation settings in force (each entry's controller has them under its
        features and law)."""
        return self._settings

    @property
    def job(self) -> Job | None:
        """The job in force (None: the settings' single feature)."""
        return self.entries.job

    @property
    def state(self) -> State:
        """The gravest state of the entries in force (a stopped entry is the gauge's
        stop)."""
        return max((ch.controller.state for _, ch in self.in_force()), key=_GRAVITY.index)

    def in_force(self) -> list[tuple[OffsetEntry, OffsetChannel]]:
        """The offsets' channels of the job in force by entry, for every reader."""
        return self.entries.in_force()

    def last_measurement_seq(self) -> int:
        """The latest measurement any entry in force took (-1: none)."""
        return max(ch.controller.persisted.last_measurement_seq for _, ch in self.in_force())

    def log_problem(self) -> str:
        """Why the decision log cannot be written now ("" when it can)."""
        return self.log.problem if self.log is not None else ""

    def last_write(self) -> WriteResult | None:
        """The latest offset write of any channel in force."""
        written = [ch for _, ch in self.in_force() if ch.last_write is not None]
        return max(written, key=lambda ch: ch.last_write_s).last_write if written else None

    def feature(self) -> Feature:
        """Nominal and tolerance of the settings (the single feature's)."""
        s = self.settings
        return Feature(s.nominal_mm, s.tol_lower_mm, s.tol_upper_mm)

    def offset_hold(self) -> str | None:
        """Why offsets are held now, or None."""
        h = self._hold
        return h.why if h is not None and time.monotonic() < h.until_s else None

    def status(self) -> dict[str, Any]:
        """The compensation's part of the service status: each entry's under ``entries``;
        at the top, the one entry's offsets when the job has one (None with several)."""
        entries = self.entries.status()
        one = entries[0] if len(entries) == 1 else {}
        return {"state": self.state.value, "shadow": self.settings.shadow,
                **{k: one.get(k) for k in (
                    "cumulative_offset_mm", "cnc_total_mm", "baseline_mm",
                    "cnc_offset_from_baseline_mm", "offset_seq", "pending_seq",
                    "dead_time")},
                "max_total_mm": self.settings.max_total_mm, "held": self.offset_hold(),
                "log_rows": None if self.log is None else self.log.rows_written,
                "entries": entries}

    # ---- the measurements ----------------------------------------------------------------

    def set_job(self, job: Job | None) -> None:
        """The job in force (None: the settings' single feature): a channel for each of its
        offset entries, each measurement judged against its feature and taken into its
        entry's law."""
        if (ended := self._segments.flush()) is not None:
            self._queued(*ended)
        self.entries.set_job(job, self.settings, self._calibration_id)

    def submit(self, record: MeasurementRecord, received_s: float, held: str | None = None,
               feature: JobFeature | None = None) -> None:
        """Queue a published measurement (of ``feature`` of the job) for the controller (the
        oldest is dropped and counted when the queue is full). Held measurements go in with a
        held status: while offsets are held, or when ``held`` names why this one may not move
        the tool (``held_for_<held>``). With ``judge = "segment"`` a job's good frames go
        in a segment at a time, fused (``SegmentFusion``)."""
        if self._queue is None:
            return
        hold = self._hold.code if self.offset_hold() and self._hold else held
        if self.log_problem():  # an offset that cannot be logged is not written, nor
            hold = "log_unwritable"  # proposed anew with each measurement meanwhile
        m = MeasurementIn(
            record.seq, received_s, ("held_for_" + hold) if hold else record.status,
            record.compensation_diameter_mm, record.uncertainty_mm, record.calibration_id)
        if self.settings.judge == "segment" and feature is not None and m.status == "ok" \
                and m.diameter_mm is not None and m.uncertainty_mm is not None:
            ended = self._segments.add(m, feature, feature.number)
            if ended is None:
                return
            m, feature = ended
        self._queued(m, feature)

    def _queued(self, m: MeasurementIn, feature: JobFeature | None) -> None:
        if self._queue is None:
            return
        if self._queue.full():
            self._queue.get_nowait()
            self.dropped += 1
        self._queue.put_nowait((m, feature))

    async def run(self) -> None:
        """Judge queued measurements until cancelled."""
        self._queue = asyncio.Queue(QUEUE_SIZE)
        while True:
            m, feature = await self._queue.get()
            try:
                await self.entries.judge(m, feature)
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
        self._calibration_id = calibration_id
        self.entries.set_calibration(calibration_id)

    def set_writes_blocked(self, why: str) -> None:
        """Offsets are only proposed while ``why`` is not empty (a master check)."""
        self.entries.set_writes_blocked(why)

    async def update_settings(self, settings: CompensationSettings, who: str) -> Decision:
        """New compensation settings (ValueError naming the bad one), stored before they are
        in force (NotStoredError, nothing changed, when they cannot be), and logged with who
        changed what, by every entry. Tuning that a feature of the job in force could not
        hold (a null band wider than its tolerance) is refused naming the feature: the job
        is checked with the same rules when it is stored."""
        job = self.job
        problems = settings.problems()
        if job is not None and not job.is_single:
            problems += job.tuning_problems(settings)
        for _, ch in self.in_force():
            try:
                ch.controller.check_settings(own_settings(job, ch.entry or SETTINGS_ENTRY,
                                                          settings))
            except ValueError as err:
                problems.append(str(err))
        if problems:
            raise ValueError("; ".join(dict.fromkeys(problems)))
        await self._save(RuntimeSettings(settings, self.part_temp_c, self.alpha_per_k))
        self._settings = settings
        decisions = await self.entries.update_settings(settings, who)
        self._settings_changed.tell(settings)
        return decisions[0]

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

        await self.in_force()[0][1].note_settings(
            f"temperature changed (part_temp_c={part_temp_c!r}, alpha_per_k={alpha!r})", who,
            lambda: self._save(RuntimeSettings(self.settings, part_temp_c, alpha)), apply)

    async def reset(self, source: str, who: str, tool: int | None = None) -> Decision:
        """Reset compensation: ``tool``'s entries, or (None) every entry's. From the CNC's
        command register (``source`` "modbus") it is refused and logged unless
        ``reset_command`` allows it; a reset moves the reference of the cumulative limit to
        where the CNC's total stands. KeyError when ``tool`` has no compensation."""
        if source == "modbus" and not self.reset_command:
            return await self.in_force()[0][1].refuse_reset(
                who, "resets from the CNC's command register are off (modbus.reset_command); "
                "a technician resets over the API")
        return await self._command("reset", who, tool)

    async def insert_change(self, who: str, tool: int) -> Decision:
        """A person recorded an insert change of ``tool`` (its wear offset zeroed at the
        CNC): its entries reset, the process estimated again from the new insert's parts
        (KeyError when ``tool`` has no compensation)."""
        return await self._command("insert_change", who, tool)

    async def acknowledge(self, who: str, tool: int | None = None) -> Decision:
        """Acknowledge an out-of-tolerance alarm (``tool``'s entries', or every one's)."""
        return await self._command("acknowledge", who, tool)

    async def _command(self, action: str, who: str, tool: int | None) -> Decision:
        decisions = [await ch.command(action, who) for ch in self.entries.select(tool)]
        return decisions[0]

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
