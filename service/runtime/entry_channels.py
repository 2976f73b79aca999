"""The offsets' channels of the job in force: one for each offset entry it corrects (a
tool's own, or another offset of the same insert), each with its own controller, state kept
in the store (``entry_states``), transport and settling. With no job in force the settings'
single feature is tool 1's own entry (``SETTINGS_ENTRY``): one path for every job.

An offset reaches an entry only through that entry's transport: the pull handshake's request
names the tool and the entry (map v5), the push writer writes to the entry's own block of
the CNC's registers (``plc.tool_stride``). Entries that would share one transport (a CNC that
keeps one block, for a job of two entries) get none: their offsets are proposed and logged,
never written, and the block says why.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable
from typing import Any

from calib_store.compensation_log import CompensationLog
from drivers.plc.client import WriteResult
from service.compensation import (
    CompensationController,
    CompensationSettings,
    ControllerState,
    Decision,
    MeasurementIn,
)
from service.compensation.entries import EntryCompensation
from service.compensation.job import Job, JobFeature, OffsetEntry
from service.runtime.listeners import Listeners
from service.runtime.offset_channel import OffsetChannel, OffsetTransport

log = logging.getLogger("shaftgauge.compensation")

SETTINGS_ENTRY = OffsetEntry(1)
"""The entry of the settings' single feature (``Job.single`` finishes it with tool 1)."""

Transports = Callable[[OffsetEntry], OffsetTransport]
"""An entry -> its transport (ValueError naming why the CNC keeps none for it)."""


def own_settings(job: Job | None, entry: OffsetEntry, base: CompensationSettings
                 ) -> CompensationSettings:
    """An entry's controller settings: ``base`` with its tool's law and the bands of the
    first feature on it (each measurement is then judged against its own feature's); with
    no job, ``base``."""
    return base if job is None else job.settings_for(job.features_on(entry)[0], base)


class EntryChannels:
    """The channels of the entries in force.

    Parameters
    ----------
    transport : callable or None
        Entry -> its transport (``PullCnc.entry``, ``OffsetWriter.offset``); None: no CNC
        connection (nothing is ever written).
    log_ : CompensationLog or None
        Decisions and each entry's state.
    on_decision : callable
        Told every decision (named by its entry).
    writes : Listeners
        Told every offset write; every entry's channel shares them.
    """

    def __init__(self, transport: Transports | None, log_: CompensationLog | None,
                 on_decision: Callable[[Decision], None],
                 writes: Listeners[WriteResult] | None = None) -> None:
        self.transport, self.log, self.on_decision = transport, log_, on_decision
        self.writes = writes if writes is not None else Listeners("offset write")
        self.channels: dict[OffsetEntry, OffsetChannel] = {}
        self.job: Job | None = None
        self._resumed: set[int] = set()  # id() of the channels offered their offset again
        self._gate = ""  # the master gate's reason, for every entry
        self._retuning: set[asyncio.Task] = set()
        self._no_transport: dict[OffsetEntry, str] = {}  # entry -> why it has none
        self._shared: dict[OffsetEntry, str] = {}  # entry -> the entries it shares one with

    def set_job(self, job: Job | None, base: CompensationSettings,
                calibration_id: int | None) -> None:
        """The job in force (None: the settings' single feature): a channel for each of its
        entries (an entry kept from the job before keeps its controller)."""
        entries = job.entries() if job is not None else (SETTINGS_ENTRY,)
        for e in set(self.channels) - set(entries):
            self._drop(e)
        for e in entries:
            own = own_settings(job, e, base)
            ch = self.channels.get(e)
            if ch is None:
                ch = self.channels[e] = self._channel(e, own, calibration_id)
            elif ch.controller.settings != own:  # a new job, or a new version of it
                self._retune(ch, own, "job")
            ch.compensation = None if job is None else EntryCompensation(
                job, e, base, controller=ch.controller)
        self.job = job
        self._share_check()

    def _share_check(self) -> None:
        """Entries whose transports are one (a CNC that keeps one block) may not write."""
        by_transport: dict[int, list[OffsetEntry]] = {}
        for e, ch in self.channels.items():
            if ch.writer is not None:
                by_transport.setdefault(id(ch.writer), []).append(e)
        self._shared = {
            e: (f"{e}'s offsets cannot be sent: the CNC keeps one offset block for "
                f"{' and '.join(map(str, sharing))} (plc.tool_stride = 0); set "
                "plc.tool_stride to where it keeps each entry's block, or use the pull "
                "handshake (plc.source = \"pull\"), whose requests name the entry")
            for sharing in by_transport.values() if len(sharing) > 1 for e in sharing}
        self.set_writes_blocked(self._gate)

    def _why_blocked(self, entry: OffsetEntry) -> str:
        """Why ``entry``'s offsets may never be written here ("" when they may)."""
        return self._no_transport.get(entry, "") or self._shared.get(entry, "")

    def _retune(self, ch: OffsetChannel, settings: CompensationSettings, who: str) -> None:
        """New settings for a channel, in turn with what it is doing (its lock), logged."""
        try:
            loop = asyncio.get_running_loop()
        except RuntimeError:  # not running yet (the service starting): nothing is in flight
            ch.controller.update_settings(settings, ch.clock(), who)
            return
        task = loop.create_task(ch.update_settings(settings, who))
        self._retuning.add(task)
        task.add_done_callback(self._retuning.discard)

    def _channel(self, entry: OffsetEntry, own: CompensationSettings,
                 calibration_id: int | None) -> OffsetChannel:
        state = ControllerState.from_dict(
            self.log.load_state(entry.tool, entry.number or 0) if self.log else None)
        transport = None
        try:
            transport = self.transport(entry) if self.transport else None
        except ValueError as err:  # the CNC keeps no block for this entry
            self._no_transport[entry] = f"{entry}'s offsets cannot be sent: {err}"
        ch = OffsetChannel(CompensationController(own, state), transport, self.log,
                           on_decision=self.on_decision, entry=entry)
        ch.writes = self.writes
        ch.set_calibration(calibration_id)
        log.info("%s: its own compensation (state %s)", entry, ch.controller.state.value)
        return ch

    def _drop(self, entry: OffsetEntry) -> None:
        ch = self.channels.pop(entry)
        self._no_transport.pop(entry, None)
        if ch.controller.persisted.pending_seq is not None:
            log.warning("%s left the job with offset %d unsettled: it is settled when a job "
                        "with the entry is in force again", entry,
                        ch.controller.persisted.pending_seq)

    def in_force(self) -> list[tuple[OffsetEntry, OffsetChannel]]:
        """Every entry's channel, in the job's order of entries."""
        return list(self.channels.items())

    def channel_of(self, feature: JobFeature | None) -> OffsetChannel:
        """The channel of ``feature``'s entry; a measurement of no feature goes to the
        first entry's, which refuses or holds it (logged once, never judged)."""
        if feature is not None and self.job is not None:
            ch = self.channels.get(self.job.entry_of(feature))
            if ch is not None:
                return ch
        return next(iter(self.channels.values()))

    def select(self, tool: int | None = None) -> list[OffsetChannel]:
        """The channels of ``tool``'s entries (None: every entry's); KeyError naming the
        tools there are when ``tool`` has none."""
        if tool is None:
            return list(self.channels.values())
        chosen = [ch for e, ch in self.channels.items() if e.tool == tool]
        if not chosen:
            raise KeyError(f"tool {tool} has no compensation: the job in force has tools "
                           f"{sorted({e.tool for e in self.channels})}")
        return chosen

    # ---- what changes every entry ---------------------------------------------------------

    def set_calibration(self, calibration_id: int | None) -> None:
        """Only measurements of this calibration count, for every entry."""
        for ch in self.channels.values():
            ch.set_calibration(calibration_id)

    def set_writes_blocked(self, why: str) -> None:
        """The master gate for every entry (an entry without a transport of its own stays
        blocked for that)."""
        self._gate = why
        for e, ch in self.channels.items():
            ch.set_writes_blocked(why or self._why_blocked(e))

    def blocked(self) -> str:
        """Why some entry's offsets may not be written, other than the master gate ("" when
        every one's may)."""
        return next((w for w in map(self._why_blocked, self.channels) if w), "")

    async def update_settings(self, settings: CompensationSettings, who: str
                              ) -> list[Decision]:
        """New settings under every entry's features and law (stored already by the
        caller): each entry's decision."""
        job = self.job
        if job is not None and job.is_single and settings.nominal_mm is not None:
            job = self.job = Job.single(settings)  # the settings' feature: it follows them
        out = []
        for e, ch in list(self.channels.items()):
            out.append(await ch.update_settings(own_settings(job, e, settings), who))
            if job is not None:
                ch.compensation = EntryCompensation(job, e, settings, controller=ch.controller)
        return out

    # ---- running ---------------------------------------------------------------------------

    async def judge(self, m: MeasurementIn, feature: JobFeature | None) -> None:
        """Judge ``m`` with its feature's entry's channel."""
        await self.channel_of(feature).on_measurement(m, feature)

    async def run_settlers(self, period_s: float = 1.0) -> None:
        """Every entry's settling (``OffsetChannel.tick``), an unsettled offset offered again
        once per channel first; runs until cancelled."""
        while True:
            for ch in list(self.channels.values()):
                if id(ch) not in self._resumed:
                    self._resumed.add(id(ch))
                    try:
                        await ch.resume()
                    except Exception:  # settling still works without it
                        log.exception("offering %s's unsettled offset again failed", ch.entry)
                await ch.tick()
            await asyncio.sleep(period_s)

    def status(self) -> list[dict[str, Any]]:
        """Each entry's compensation, JSON-ready."""
        out = []
        for e, ch in self.channels.items():
            c, p = ch.controller, ch.controller.persisted
            out.append({"tool": e.tool, "entry": e.number,
                        "features": [f.number for f in self.job.features_on(e)]
                        if self.job is not None else [],
                        "state": c.state.value, "shadow": c.settings.shadow,
                        "cumulative_offset_mm": c.cumulative_mm, "cnc_total_mm": p.cnc_total_mm,
                        "baseline_mm": p.baseline_mm,
                        "cnc_offset_from_baseline_mm": p.cnc_offset_mm(),
                        "offset_seq": p.offset_seq, "pending_seq": p.pending_seq,
                        "writes_blocked": c.writes_blocked or None,
                        "dead_time": c.dead.status(c.settings.dead_time_measurements,
                                                   c.settings.dead_time_s)})
        return out
