"""A job of several tools in the running service's compensation: each tool's offsets go to
its own transport only, each tool's state survives a restart in the store, a reset names its
tool, and a CNC that keeps no block a tool has offsets proposed, none written."""

from __future__ import annotations

import asyncio
import time
from dataclasses import replace
from pathlib import Path

import pytest

from calib_store.compensation_log import CompensationLog
from service.compensation import Kind, MeasurementIn
from service.compensation.job import job_from_doc
from service.runtime.compensating import CompensationService, RuntimeSettings
from service.runtime.tool_channels import NO_TOOL_IN_HANDSHAKE
from tests.unit.test_cnc_loop import LIVE, FakeCnc

DOC = {"part_number": "SH-2T", "name": "two tools", "features": [
    {"number": 1, "name": "journal", "nominal_mm": 30.0, "tol_upper_mm": 0.05,
     "tol_lower_mm": -0.05, "tool": 1},
    {"number": 2, "name": "seat", "nominal_mm": 25.0, "tol_upper_mm": 0.05,
     "tol_lower_mm": -0.05, "tool": 2}]}


def service(path: Path, cncs: dict[int, FakeCnc] | None, primary: FakeCnc | None
            ) -> CompensationService:
    comp = CompensationService(RuntimeSettings(LIVE, None, 11.5e-6), primary,
                               CompensationLog(path),
                               tool_transport=None if cncs is None else cncs.__getitem__)
    comp.set_job(job_from_doc(DOC, LIVE))
    return comp


async def cut(comp: CompensationService, seq0: int, parts: int,
              off_um: dict[int, float]) -> int:
    """``parts`` parts, each feature off its nominal by ``off_um`` less what its tool's CNC
    has applied so far."""
    job = job_from_doc(DOC, LIVE)
    seq = seq0
    for _ in range(parts):
        for f in job.features:
            ch = comp.tools.channel(f.tool)
            await ch.tick()  # the settler: the CNC's total, the baseline
            applied = getattr(ch.writer, "total_mm", 0.0)
            seq += 1
            await comp.tools.judge(MeasurementIn(seq, time.monotonic(), "ok", f.nominal_mm
                                                 + off_um[f.tool] / 1000 + applied, 0.001), f)
    return seq


async def test_each_tool_is_corrected_through_its_own_transport_and_kept(tmp_path) -> None:
    cncs, primary = {1: FakeCnc(), 2: FakeCnc()}, FakeCnc()
    comp = service(tmp_path / "g.db", cncs, primary)
    assert sorted(comp.tools.channels) == [1, 2]
    seq = await cut(comp, 0, 12, {1: +8.0, 2: -6.0})
    assert cncs[1].applied and cncs[2].applied and not primary.sent
    assert sum(v for _, v in cncs[1].applied) < 0 < sum(v for _, v in cncs[2].applied)
    # Each tool's own sequence: no offset of one reached the other's transport.
    assert [s for s, _ in cncs[1].applied] == list(range(1, len(cncs[1].applied) + 1))
    assert [s for s, _ in cncs[2].applied] == list(range(1, len(cncs[2].applied) + 1))
    before = {t: ch.controller.persisted.offset_seq for t, ch in comp.tools.channels.items()}
    status = {t["tool"]: t for t in comp.status()["tools"]}
    assert status[2]["cumulative_offset_mm"] > 0 > status[1]["cumulative_offset_mm"]
    d = await comp.reset("api", "api:technician", tool=2)
    assert d.kind is Kind.RESET and d.tool == 2
    with pytest.raises(KeyError, match=r"has tools \[1, 2\]"):
        await comp.reset("api", "api:technician", tool=3)
    comp.log.close()
    # A restart: each tool takes up its own state from the store.
    again = service(tmp_path / "g.db", cncs, primary)
    assert {t: ch.controller.persisted.offset_seq for t, ch in again.tools.channels.items()
            } == before
    await cut(again, seq, 2, {1: 0.0, 2: 0.0})
    rows = again.log.decisions(limit=1000)
    assert {r["tool"] for r in rows if r["kind"] == "applied"} == {1, 2}
    again.log.close()


async def test_a_cnc_with_one_offset_block_only_has_offsets_proposed(tmp_path) -> None:
    primary = FakeCnc()
    comp = service(tmp_path / "g.db", None, primary)
    assert comp.tools.blocked == NO_TOOL_IN_HANDSHAKE
    await cut(comp, 0, 12, {1: +8.0, 2: -6.0})
    assert not primary.sent
    rows = comp.log.decisions(limit=1000)
    proposed = [r for r in rows if r["kind"] == "proposed"]
    assert {r["tool"] for r in proposed} == {1, 2}, rows[:5]
    assert "keeps one offset block" in proposed[0]["reason"]
    assert "plc.tool_stride" in comp.status()["tools"][0]["writes_blocked"]
    comp.log.close()


async def test_settings_reach_every_tool_and_a_job_of_one_tool_has_no_channels(tmp_path
                                                                               ) -> None:
    comp = service(tmp_path / "g.db", {1: FakeCnc(), 2: FakeCnc()}, FakeCnc())
    await comp.update_settings(replace(comp.settings, shadow=True), "api:technician")
    assert all(ch.controller.settings.shadow for ch in comp.tools.channels.values())
    # A new version of the job gives tool 2 a law of its own: its controller takes it.
    comp.set_job(job_from_doc({**DOC, "tools": [{"number": 2, "gain": 0.3}]}, LIVE))
    await asyncio.sleep(0.01)  # the change, in turn with the channel's work
    assert comp.tools.channel(2).controller.settings.gain == 0.3
    assert comp.tools.channel(1).controller.settings.gain == LIVE.gain
    assert comp.tools.channel(2).controller.settings.nominal_mm == 25.0
    comp.set_job(job_from_doc({**DOC, "features": DOC["features"][:1]}, LIVE))
    assert comp.tools.channels == {} and comp.status()["tools"] == []
    comp.log.close()


async def test_a_tool_the_cnc_keeps_no_block_for_is_proposed_only(tmp_path) -> None:
    def transport(tool: int) -> FakeCnc:
        if tool == 2:
            raise ValueError("tool 2's block would lie beyond register 65535")
        return FakeCnc()

    comp = CompensationService(RuntimeSettings(LIVE, None, 11.5e-6), FakeCnc(),
                               CompensationLog(tmp_path / "g.db"), tool_transport=transport)
    comp.set_job(job_from_doc(DOC, LIVE))
    tools = {t["tool"]: t for t in comp.status()["tools"]}
    assert tools[1]["writes_blocked"] is None
    assert "beyond register 65535" in tools[2]["writes_blocked"]
    comp.set_writes_blocked("master check overdue")  # the gate passes; the block stays
    comp.set_writes_blocked("")
    assert "beyond register 65535" in comp.tools.channel(2).controller.writes_blocked
    comp.log.close()


def test_readers_see_the_channels_of_the_job_in_force(tmp_path) -> None:
    """Every reader takes ``in_force``: each tool's channel in a job of several, the one
    channel otherwise; the gauge's state is the gravest of those, not of the one channel
    that no tool of the job uses (stopped before the job, say)."""
    from service.compensation import State

    comp = service(tmp_path / "log.db", {1: FakeCnc(), 2: FakeCnc()}, FakeCnc())
    assert [t for t, _ in comp.in_force()] == [1, 2]
    comp.channel.controller.persisted.state = State.STOPPED.value
    assert comp.state is not State.STOPPED
    comp.tools.channels[2].controller.persisted.state = State.ALARM.value
    assert comp.state is State.ALARM
    comp.set_job(None)
    assert comp.in_force() == [(None, comp.channel)] and comp.state is State.STOPPED
