"""The tools of a job of several: one offset channel per tool, each with its own controller,
state kept in the store (``tool_states``), CNC transport and settling. The single channel of
``CompensationService`` stays for a job of one tool and for the settings' single feature.

An offset reaches a tool only through that tool's transport: the pull handshake's request
names it (map v4), the push writer writes to the tool's own block of the CNC's registers
(``plc.tool_stride``). A CNC with one block gets no transport a tool: each tool's offsets are
then proposed and logged, never written, and the block says why.
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
from service.compensation.job import Job, JobFeature
from service.compensation.tools import ToolCompensation
from service.offset_channel import OffsetChannel, OffsetTransport
from service.runtime.listeners import Listeners

log = logging.getLogger("shaftgauge.compensation")

NO_TOOL_IN_HANDSHAKE = (
    "the CNC keeps one offset block (plc.tool_stride = 0), so the offsets of a job of several "
    "tools are only proposed: set plc.tool_stride to where it keeps each tool's block, or use "
    "the pull handshake (plc.source = \"pull\", register map v4), whose requests name the "
    "tool")


def own_settings(job: Job, tool: int, base: CompensationSettings) -> CompensationSettings:
    """A tool's controller settings: ``base`` with its law (the job's ``tools[].gain``,
    ``trend_gain``) and the bands of the first feature it finishes (each measurement is then
    judged against its own feature's)."""
    return job.settings_for(job.features_of(tool)[0], base)


class ToolChannels:
    """The channels of the job's tools (empty unless the job in force has several).

    Parameters
    ----------
    transport : callable or None
        Tool number -> its transport (``PullCnc.tool``, ``OffsetWriter.tool``); None: no
        handshake here names a tool.
    log_ : CompensationLog or None
        Decisions and each tool's state.
    on_decision : callable
        Told every decision (named by its tool).
    blocked : str
        Why the tools' offsets may never be written here (empty: they may).
    writes : Listeners
        Told every offset write; every tool's channel shares them.
    """

    def __init__(self, transport: Callable[[int], OffsetTransport] | None,
                 log_: CompensationLog | None, on_decision: Callable[[Decision], None],
                 blocked: str = "",
                 writes: Listeners[WriteResult] | None = None) -> None:
        self.transport, self.log, self.on_decision = transport, log_, on_decision
        self.blocked = blocked
        self.writes = writes if writes is not None else Listeners("offset write")
        self.channels: dict[int, OffsetChannel] = {}
        self._resumed: set[int] = set()  # id() of the channels offered their offset again
        self._gate = ""  # the master gate's reason, for every tool
        self._retuning: set[asyncio.Task] = set()
        self._no_transport: dict[int, str] = {}  # tool -> why it has no transport

    def set_job(self, job: Job | None, base: CompensationSettings,
                calibration_id: int | None) -> None:
        """The job in force: a channel for each of its tools when it has several (a tool
        kept from the job before keeps its controller), none otherwise."""
        tools = job.tool_numbers() if job is not None else ()
        if job is None or len(tools) < 2:
            self._drop(set(self.channels))
            return
        self._drop(set(self.channels) - set(tools))
        for t in tools:
            own = own_settings(job, t, base)
            ch = self.channels.get(t)
            if ch is None:
                ch = self.channels[t] = self._channel(t, own, calibration_id)
            elif ch.controller.settings != own:  # a new version of the job: the tool's law
                self._retune(ch, own, "job")
            ch.tool = ToolCompensation(job, t, base, controller=ch.controller)

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

    def _channel(self, tool: int, own: CompensationSettings,
                 calibration_id: int | None) -> OffsetChannel:
        state = ControllerState.from_dict(self.log.load_state(tool) if self.log else None)
        transport = None
        try:
            transport = self.transport(tool) if self.transport else None
        except ValueError as err:  # the CNC keeps no block for this tool
            self._no_transport[tool] = f"tool {tool}'s offsets cannot be sent: {err}"
        ch = OffsetChannel(CompensationController(own, state), transport, self.log,
                           on_decision=self.on_decision, tool_number=tool)
        ch.writes = self.writes
        ch.set_calibration(calibration_id)
        ch.set_writes_blocked(self._why_blocked(tool))
        log.info("tool %d: its own compensation (state %s)", tool, ch.controller.state.value)
        return ch

    def _drop(self, tools: set[int]) -> None:
        for t in tools:
            ch = self.channels.pop(t)
            if ch.controller.persisted.pending_seq is not None:
                log.warning("tool %d left the job with offset %d unsettled: it is settled "
                            "when a job with the tool is in force again", t,
                            ch.controller.persisted.pending_seq)

    def channel_of(self, feature: JobFeature | None) -> OffsetChannel | None:
        """The channel of the tool finishing ``feature`` (None: not a tool's of several)."""
        return None if feature is None else self.channels.get(feature.tool)

    def channel(self, tool: int) -> OffsetChannel:
        """Tool ``tool``'s channel (KeyError naming the tools there are)."""
        if tool not in self.channels:
            has = f"has tools {sorted(self.channels)}" if self.channels else \
                "has one tool at most (the single compensation is its)"
            raise KeyError(f"tool {tool} has no compensation of its own: the job in force {has}")
        return self.channels[tool]

    # ---- what changes every tool ----------------------------------------------------------

    def set_calibration(self, calibration_id: int | None) -> None:
        """Only measurements of this calibration count, for every tool."""
        for ch in self.channels.values():
            ch.set_calibration(calibration_id)

    def set_writes_blocked(self, why: str) -> None:
        """The master gate (and a handshake naming no tool) for every tool."""
        self._gate = why
        for t, ch in self.channels.items():
            ch.set_writes_blocked(self._why_blocked(t))

    def _why_blocked(self, tool: int) -> str:
        return self._gate or self.blocked or self._no_transport.get(tool, "")

    async def update_settings(self, settings: CompensationSettings, who: str) -> None:
        """New settings under every tool's features and law (stored already by the
        caller)."""
        for t, ch in list(self.channels.items()):
            if ch.tool is not None:
                await ch.update_settings(own_settings(ch.tool.job, t, settings), who)
                ch.tool.rebase(settings)

    async def command(self, action: str, who: str, tool: int | None = None
                      ) -> list[Decision]:
        """``reset`` or ``acknowledge`` for ``tool`` (None: every tool)."""
        chosen = [self.channel(tool)] if tool is not None else list(self.channels.values())
        return [await ch.command(action, who) for ch in chosen]

    # ---- running ---------------------------------------------------------------------------

    async def judge(self, m: MeasurementIn, feature: JobFeature) -> bool:
        """Judge ``m`` with its feature's tool's channel; False when no tool of several
        finishes it (the single channel judges it)."""
        ch = self.channel_of(feature)
        if ch is None:
            return False
        await ch.on_measurement(m, feature)
        return True

    async def run_settlers(self, period_s: float = 1.0) -> None:
        """Every tool's settling (``OffsetChannel.tick``), an unsettled offset offered again
        once per channel first; runs until cancelled."""
        while True:
            for ch in list(self.channels.values()):
                if id(ch) not in self._resumed:
                    self._resumed.add(id(ch))
                    try:
                        await ch.resume()
                    except Exception:  # settling still works without it
                        log.exception("offering tool %s's unsettled offset again failed",
                                      ch.tool_number)
                await ch.tick()
            await asyncio.sleep(period_s)

    def status(self) -> list[dict[str, Any]]:
        """Each tool's compensation, JSON-ready."""
        out = []
        for t, ch in sorted(self.channels.items()):
            c, p = ch.controller, ch.controller.persisted
            out.append({"tool": t, "features": [f.number for f in ch.tool.job.features_of(t)]
                        if ch.tool else [], "state": c.state.value, "shadow": c.settings.shadow,
                        "cumulative_offset_mm": c.cumulative_mm, "cnc_total_mm": p.cnc_total_mm,
                        "baseline_mm": p.baseline_mm, "offset_seq": p.offset_seq,
                        "pending_seq": p.pending_seq,
                        "writes_blocked": c.writes_blocked or None})
        return out
