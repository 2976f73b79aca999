"""Offsets to the simulated CNC over real Modbus TCP: once each, verified, never re-sent."""

from __future__ import annotations

import asyncio
import json
from dataclasses import replace

import pytest

from calib_store.compensation_log import CompensationLog
from drivers.plc.client import OffsetWriter, Outcome
from drivers.plc.offset_map import PlcOffsetMap
from service.compensation import (
    CompensationController,
    CompensationSettings,
    ControllerState,
    Kind,
    MeasurementIn,
    State,
)
from service.runtime.offset_channel import OffsetChannel

# The window law with the tuning these handshakes were written with (a write when the third
# measurement fills the window); the exchange does not depend on the law.
LIVE = CompensationSettings(nominal_mm=30.0, shadow=False, window=3, law="window", gain=0.7,
                            deadband_mm=0.003, dead_time_measurements=0, dead_time_s=0.0)


def plc_log(path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines()] if path.exists() else []


def applied_seqs(path) -> list[int]:
    return [e["seq"] for e in plc_log(path) if e["event"] == "applied"]


async def test_an_offset_is_applied_once_and_verified(sim_plc_factory) -> None:
    plc = sim_plc_factory()
    writer = OffsetWriter("127.0.0.1", plc.port)
    r = await writer.write_offset(-0.0056, 1)
    assert r.outcome is Outcome.APPLIED and r.value_units == -56, r
    assert "verified" in r.message
    assert await writer.read_ack() == 1
    await writer.close()
    assert applied_seqs(sim_plc_factory.log) == [1]


async def test_unreachable_plc_is_not_applied_and_reported() -> None:
    writer = OffsetWriter("127.0.0.1", 1, reconnect_initial_s=0.05)  # nothing listens on 1
    r = await writer.write_offset(0.002, 1)
    assert r.outcome is Outcome.NOT_APPLIED and "unreachable" in r.message
    assert not writer.connected and writer.outage_since is not None


async def test_slow_acknowledgement_is_unknown_then_settled(sim_plc_factory) -> None:
    plc = sim_plc_factory(None, "--ack-delay", "1.0")
    writer = OffsetWriter("127.0.0.1", plc.port, ack_timeout_s=0.3)
    r = await writer.write_offset(0.003, 5)
    assert r.outcome is Outcome.UNKNOWN and "acknowledgement" in r.message
    await asyncio.sleep(1.0)
    assert await writer.read_ack() == 5  # it did land, later
    await writer.close()


async def test_plc_killed_mid_write_and_restarted(sim_plc_factory, tmp_path) -> None:
    """No offset applied twice, none lost silently, the outage reported."""
    plc = sim_plc_factory(None, "--ack-delay", "1.0")
    writer = OffsetWriter("127.0.0.1", plc.port, ack_timeout_s=3.0,
                          reconnect_initial_s=0.1, reconnect_max_s=0.3)
    store = CompensationLog(tmp_path / "comp.db")
    channel = OffsetChannel(CompensationController(LIVE), writer, store)
    assert (await channel.refresh()).kind is Kind.BASELINE  # the CNC's total, read first
    seq = 0

    async def measure(d: float) -> list:
        nonlocal seq
        seq += 1
        now = channel.clock()
        return await channel.on_measurement(MeasurementIn(seq, now, "ok", d, 0.001))

    await measure(30.008)
    await measure(30.008)
    writing = asyncio.create_task(measure(30.008))  # the third fills the window: a write
    await asyncio.sleep(0.4)                        # the write is in, the ack not yet
    plc.kill()
    decisions = await writing
    assert [d.kind for d in decisions] == [Kind.WRITE, Kind.UNCERTAIN]
    assert channel.controller.state is State.UNCERTAIN
    assert not writer.connected and writer.outage_since is not None  # the outage is known
    # Measurements keep coming; nothing is written while the offset is unsettled.
    for _ in range(4):
        assert (await measure(30.008))[0].kind is Kind.HELD
    assert await channel.settle() is None  # the PLC is still down: cannot settle yet
    sim_plc_factory(plc.port, "--ack-delay", "1.0")  # back, same port, same state file
    settled = None
    for _ in range(40):
        settled = await channel.settle()
        if settled:
            break
        await asyncio.sleep(0.1)
    assert settled is not None and settled.kind is Kind.NOT_APPLIED, settled
    assert "not be sent again" in settled.reason
    # A fresh offset from fresh measurements is written once, with a new sequence number.
    out = []
    for _ in range(3):
        out += await measure(30.008)
    assert [d.kind for d in out][-2:] == [Kind.WRITE, Kind.APPLIED]
    assert out[-1].offset_seq == 2
    events = plc_log(sim_plc_factory.log)
    writes = [e["seq"] for e in events if e["event"] == "write"]
    assert writes == [1, 2]                      # each sent exactly once
    assert applied_seqs(sim_plc_factory.log) == [2]  # 1 died with the PLC, 2 applied once
    kinds = [d["kind"] for d in store.decisions(limit=100)]
    assert {"uncertain", "not_applied", "applied"} <= set(kinds)  # all on record
    assert store.load_state()["cumulative_mm"] == channel.controller.cumulative_mm
    await writer.close()
    store.close()


async def test_cumulative_offset_survives_a_restart(sim_plc_factory, tmp_path) -> None:
    plc = sim_plc_factory()
    writer = OffsetWriter("127.0.0.1", plc.port)
    store = CompensationLog(tmp_path / "comp.db")
    channel = OffsetChannel(CompensationController(LIVE), writer, store)
    assert (await channel.refresh()).kind is Kind.BASELINE  # the CNC's total, read first
    for i in range(3):
        await channel.on_measurement(MeasurementIn(i, channel.clock(), "ok", 30.008, 0.001))
    cum = channel.controller.cumulative_mm
    assert cum < 0
    store.close()
    again = CompensationLog(tmp_path / "comp.db")
    restored = CompensationController(replace(LIVE),
                                      ControllerState.from_dict(again.load_state()))
    assert restored.cumulative_mm == cum and restored.persisted.offset_seq == 1
    again.close()
    await writer.close()


async def test_an_offset_that_cannot_be_logged_is_not_written(sim_plc_factory, small_disk
                                                              ) -> None:
    """The decision log on a full disk: the offset is not written, the problem is said, and
    once there is room again offsets are logged and written as before."""
    plc = sim_plc_factory()
    writer = OffsetWriter("127.0.0.1", plc.port)
    store = CompensationLog(small_disk.path / "comp.db")
    channel = OffsetChannel(CompensationController(LIVE), writer, store)
    assert (await channel.refresh()).kind is Kind.BASELINE  # the CNC's total, read first
    small_disk.fill()
    seq, out = 0, []
    for _ in range(4):
        seq += 1
        out += await channel.on_measurement(MeasurementIn(seq, channel.clock(), "ok", 30.010,
                                                          0.001))
    assert "cannot be written" in channel.log_problem
    assert any(d.kind is Kind.NOT_APPLIED and "not written" in d.reason for d in out), out
    assert applied_seqs(sim_plc_factory.log) == []
    small_disk.free()
    for _ in range(4):
        seq += 1
        await channel.on_measurement(MeasurementIn(seq, channel.clock(), "ok", 30.010, 0.001))
    assert channel.log_problem == ""
    assert applied_seqs(sim_plc_factory.log) == [2]  # sequence 1 was never sent, never reused
    assert [d["kind"] for d in store.decisions(kinds=("applied",))] == ["applied"]
    await writer.close()


async def test_each_offset_number_has_its_own_block(sim_plc_factory, tmp_path) -> None:
    """A job of several entries over the push handshake: offset number n's offsets go to its
    own block (``(n - 1) * tool_stride`` registers on; number 1's is the first), each with
    its own acknowledgement and total, kept across the CNC's restart. A CNC with one block
    gives every number the same transport (the channels then refuse to share it)."""
    plc = sim_plc_factory(None, "--tools", "3", "--tool-stride", "10")
    writer = OffsetWriter("127.0.0.1", plc.port, PlcOffsetMap(tool_stride=10))
    one, two = writer.offset(1), writer.offset(2)
    assert one is writer.offset(1) and one.block == writer.map
    assert (await one.write_offset(-0.004, 1)).outcome is Outcome.APPLIED
    assert (await two.write_offset(0.003, 1)).outcome is Outcome.APPLIED  # its own sequence
    assert (await two.write_offset(0.001, 2)).outcome is Outcome.APPLIED
    r1, r2, r3 = await one.read_cnc(), await two.read_cnc(), await writer.offset(3).read_cnc()
    assert (r1.ack_seq, round(r1.total_mm * 1e4)) == (1, -40)
    assert (r2.ack_seq, round(r2.total_mm * 1e4)) == (2, 40)
    assert (r3.ack_seq, r3.total_mm) == (0, 0.0)  # offset 3's block untouched
    applied = [(e.get("offset", 1), e["seq"]) for e in plc_log(sim_plc_factory.log)
               if e["event"] == "applied"]
    assert applied == [(1, 1), (2, 1), (2, 2)]
    await writer.close()
    plc.stop()
    plc = sim_plc_factory(plc.port, "--tools", "3", "--tool-stride", "10")
    writer = OffsetWriter("127.0.0.1", plc.port, PlcOffsetMap(tool_stride=10))
    r2 = await writer.offset(2).read_cnc()
    assert (r2.ack_seq, round(r2.total_mm * 1e4)) == (2, 40)
    await writer.close()
    single = OffsetWriter("127.0.0.1", plc.port)
    assert single.offset(1) is single.offset(2)  # one block: one transport
    with pytest.raises(ValueError, match="shorter than a block"):
        OffsetWriter("127.0.0.1", plc.port, PlcOffsetMap(tool_stride=3)).offset(2)
