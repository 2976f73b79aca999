"""The running service's compensation, one channel an offset entry for every job: each
entry's offsets go to its own transport only, each entry's state survives a restart in the
store, a reset names its tool, entries that would share one transport (a CNC keeping one
block) have offsets proposed, none written, and a job of one feature takes the same path."""

from __future__ import annotations

import asyncio
import time
from dataclasses import replace
from pathlib import Path

import pytest

from calib_store.compensation_log import CompensationLog
from service.compensation import Kind, MeasurementIn, State
from service.compensation.job import Job, OffsetEntry, job_from_doc
from service.runtime.compensating import CompensationService, RuntimeSettings
from service.runtime.entry_channels import SETTINGS_ENTRY
from tests.unit.test_cnc_loop import LIVE, FakeCnc

DOC = {"part_number": "SH-2T", "name": "two tools", "features": [
    {"number": 1, "name": "journal", "nominal_mm": 30.0, "tol_upper_mm": 0.05,
     "tol_lower_mm": -0.05, "tool": 1},
    {"number": 2, "name": "seat", "nominal_mm": 25.0, "tol_upper_mm": 0.05,
     "tol_lower_mm": -0.05, "tool": 2}]}
# Two features of tool 2's insert on two entries (a slender pin on offset 10012).
ENTRIES = {**DOC, "part_number": "SH-2E", "features": [
    *DOC["features"], {"number": 3, "name": "pin", "nominal_mm": 20.0, "tol_upper_mm": 0.05,
                       "tol_lower_mm": -0.05, "tool": 2, "entry": 10012}]}


def service(path: Path, cncs: dict[OffsetEntry, FakeCnc] | None, doc: dict | None = None
            ) -> CompensationService:
    comp = CompensationService(RuntimeSettings(LIVE, None, 11.5e-6),
                               None if cncs is None else cncs.__getitem__,
                               CompensationLog(path))
    comp.set_job(job_from_doc(doc or DOC, LIVE))
    return comp


async def cut(comp: CompensationService, seq0: int, parts: int,
              off_um: dict[int, float]) -> int:
    """``parts`` parts, each feature off its nominal by ``off_um`` (by feature) less what its
    entry's CNC has applied so far."""
    job = comp.job
    assert job is not None
    seq = seq0
    for _ in range(parts):
        for f in job.features:
            ch = comp.entries.channels[job.entry_of(f)]
            await ch.tick()  # the settler: the CNC's total, the baseline
            applied = getattr(ch.writer, "total_mm", 0.0)
            seq += 1
            await comp.entries.judge(MeasurementIn(
                seq, time.monotonic(), "ok", f.nominal_mm + off_um[f.number] / 1000 + applied,
                0.001), f)
    return seq


async def test_each_entry_is_corrected_through_its_own_transport_and_kept(tmp_path) -> None:
    t1, t2, pin = OffsetEntry(1), OffsetEntry(2), OffsetEntry(2, 10012)
    cncs = {t1: FakeCnc(), t2: FakeCnc(), pin: FakeCnc()}
    comp = service(tmp_path / "g.db", cncs, ENTRIES)
    assert list(comp.entries.channels) == [t1, t2, pin]
    # The pin drifts the other way from the seat on the same insert: each its own entry.
    seq = await cut(comp, 0, 12, {1: +8.0, 2: -6.0, 3: +9.0})
    assert all(c.applied for c in cncs.values())
    assert sum(v for _, v in cncs[t1].applied) < 0 < sum(v for _, v in cncs[t2].applied)
    assert sum(v for _, v in cncs[pin].applied) < 0
    for c in cncs.values():  # each entry's own sequence: no offset reached another's
        assert [s for s, _ in c.applied] == list(range(1, len(c.applied) + 1))
    before = {e: ch.controller.persisted.offset_seq for e, ch in comp.entries.channels.items()}
    status = {(s["tool"], s["entry"]): s for s in comp.status()["entries"]}
    assert status[2, None]["cumulative_offset_mm"] > 0 > status[2, 10012]["cumulative_offset_mm"]
    assert status[2, 10012]["features"] == [3]
    assert comp.status()["cumulative_offset_mm"] is None  # several: each in its row
    d = await comp.reset("api", "api:technician", tool=2)
    assert d.kind is Kind.RESET and d.tool == 2
    with pytest.raises(KeyError, match=r"has tools \[1, 2\]"):
        await comp.reset("api", "api:technician", tool=3)
    comp.log.close()
    # A restart: each entry takes up its own state from the store.
    again = service(tmp_path / "g.db", cncs, ENTRIES)
    assert {e: ch.controller.persisted.offset_seq for e, ch in again.entries.channels.items()
            } == before
    await cut(again, seq, 2, {1: 0.0, 2: 0.0, 3: 0.0})
    rows = again.log.decisions(limit=1000)
    assert {(r["tool"], r["entry"]) for r in rows if r["kind"] == "applied"} == {
        (1, 0), (2, 0), (2, 10012)}
    again.log.close()


async def test_entries_sharing_one_transport_only_have_offsets_proposed(tmp_path) -> None:
    one = FakeCnc()  # a CNC that keeps one offset block: every entry's transport is it
    comp = service(tmp_path / "g.db", {OffsetEntry(1): one, OffsetEntry(2): one})
    assert "keeps one offset block for T1 and T2" in comp.entries.blocked()
    await cut(comp, 0, 12, {1: +8.0, 2: -6.0})
    assert not one.sent
    rows = comp.log.decisions(limit=1000)
    proposed = [r for r in rows if r["kind"] == "proposed"]
    assert {r["tool"] for r in proposed} == {1, 2}, rows[:5]
    assert "plc.tool_stride" in comp.status()["entries"][0]["writes_blocked"]
    # A job of one entry on that CNC: its offsets go out.
    comp.set_job(job_from_doc({**DOC, "features": DOC["features"][:1]}, LIVE))
    assert comp.entries.blocked() == ""
    await cut(comp, 1000, 12, {1: +8.0})
    assert one.sent
    comp.log.close()


async def test_settings_reach_every_entry_and_every_job_takes_one_path(tmp_path) -> None:
    comp = service(tmp_path / "g.db", {OffsetEntry(1): FakeCnc(), OffsetEntry(2): FakeCnc()})
    await comp.update_settings(replace(comp.settings, shadow=True), "api:technician")
    assert all(ch.controller.settings.shadow for ch in comp.entries.channels.values())
    # A new version of the job gives tool 2 a law of its own: its controller takes it.
    comp.set_job(job_from_doc({**DOC, "tools": [{"number": 2, "gain": 0.3}]}, LIVE))
    await asyncio.sleep(0.01)  # the change, in turn with the channel's work
    channels = comp.entries.channels
    assert channels[OffsetEntry(2)].controller.settings.gain == 0.3
    assert channels[OffsetEntry(1)].controller.settings.gain == LIVE.gain
    assert channels[OffsetEntry(2)].controller.settings.nominal_mm == 25.0
    # A job of one feature: one channel, the same kind, at the top of the status too.
    kept = channels[OffsetEntry(1)]
    comp.set_job(job_from_doc({**DOC, "features": DOC["features"][:1]}, LIVE))
    assert list(comp.entries.channels) == [OffsetEntry(1)]
    assert comp.entries.channels[OffsetEntry(1)] is kept  # its state goes on
    assert comp.entries.channels[OffsetEntry(1)].compensation is not None
    assert [s["tool"] for s in comp.status()["entries"]] == [1]
    assert comp.status()["cumulative_offset_mm"] == kept.controller.cumulative_mm
    # The settings' single feature as a job, and no job at all: tool 1's own entry.
    comp.set_job(Job.single(replace(LIVE, nominal_mm=30.0)))
    assert list(comp.entries.channels) == [SETTINGS_ENTRY]
    comp.set_job(None)
    assert list(comp.entries.channels) == [SETTINGS_ENTRY]
    comp.log.close()


async def test_an_entry_the_cnc_keeps_no_block_for_is_proposed_only(tmp_path) -> None:
    def transport(entry: OffsetEntry) -> FakeCnc:
        if entry.tool == 2:
            raise ValueError("offset 2's block would lie beyond register 65535")
        return FakeCnc()

    comp = CompensationService(RuntimeSettings(LIVE, None, 11.5e-6), transport,
                               CompensationLog(tmp_path / "g.db"))
    comp.set_job(job_from_doc(DOC, LIVE))
    entries = {s["tool"]: s for s in comp.status()["entries"]}
    assert entries[1]["writes_blocked"] is None
    assert "beyond register 65535" in entries[2]["writes_blocked"]
    comp.set_writes_blocked("master check overdue")  # the gate passes; the block stays
    comp.set_writes_blocked("")
    assert "beyond register 65535" in \
        comp.entries.channels[OffsetEntry(2)].controller.writes_blocked
    comp.log.close()


def test_readers_see_the_channels_of_the_job_in_force(tmp_path) -> None:
    """Every reader takes ``in_force``: each entry's channel; the gauge's state is the
    gravest of those, not of a channel that left with the job before (stopped, say)."""
    comp = service(tmp_path / "log.db", {OffsetEntry(1): FakeCnc(), OffsetEntry(2): FakeCnc(),
                                         OffsetEntry(2, 10012): FakeCnc()}, ENTRIES)
    assert [e for e, _ in comp.in_force()] == [OffsetEntry(1), OffsetEntry(2),
                                                OffsetEntry(2, 10012)]
    comp.entries.channels[OffsetEntry(2, 10012)].controller.persisted.state = \
        State.STOPPED.value
    assert comp.state is State.STOPPED
    comp.set_job(job_from_doc(DOC, LIVE))  # the pin's entry leaves the job
    assert comp.state is not State.STOPPED
    comp.entries.channels[OffsetEntry(2)].controller.persisted.state = State.ALARM.value
    assert comp.state is State.ALARM


async def test_the_dead_time_typed_and_measured_are_in_the_status(tmp_path) -> None:
    """Offsets written as a tool wears (the fake CNC applies each at once: a dead time of 0
    measurements, as typed): once the steps tell, each entry's status shows the dead time
    measured from them beside the typed one, the typed in use."""
    comp = service(tmp_path / "g.db", {OffsetEntry(1): FakeCnc(), OffsetEntry(2): FakeCnc()})
    before = comp.status()["entries"][0]["dead_time"]
    assert before["measured"] is None and before["in_use"] == before["typed"] == {
        "measurements": 0, "seconds": 0.0}
    seq = 0
    for k in range(60):  # each part 2 um larger than the last, both tools
        seq = await cut(comp, seq, 1, {1: 2.0 * k, 2: 2.0 * k})
    got = comp.status()["entries"][0]["dead_time"]
    assert got["measured"] is not None and got["measured"]["measurements"] == 0, got
    assert got["measured"]["steps"] >= 3 and not got["differs"]
    assert got["in_use"] == got["typed"]
    comp.log.close()
