"""The running service with a job of two tools over the pull handshake, against a CNC that
polls its Modbus server as the shipped subroutine does (read the registers, settle the request
for the tool it is called for, report that tool's total): each tool is corrected through its
own requests, and its total moves by exactly the offsets the log says it applied."""

from __future__ import annotations

import time

from fastapi.testclient import TestClient
from pymodbus.client import ModbusTcpClient

from drivers.plc.pull import REPORT, Result, settle_request, write_report
from drivers.plc.registers import (
    BY_NAME,
    ENTRY_BLOCK_BASE,
    ENTRY_BLOCK_WORDS,
    NO_VALUE,
    UM_PER_UNIT,
    RegisterBank,
)
from service.api.app import create_app
from service.runtime.plant import OpcUaValues
from service.serve import Children, build
from tests.unit.service.conftest import TECHNICIAN, make_settings
from tests.waiting import until

JOB = {"part_number": "SH-2T", "name": "two tools", "features": [
    {"number": 1, "name": "journal", "nominal_mm": 30.0, "tol_upper_mm": 0.02,
     "tol_lower_mm": -0.02, "tool": 1},
    {"number": 2, "name": "seat", "nominal_mm": 25.0, "tol_upper_mm": 0.02,
     "tol_lower_mm": -0.02, "tool": 2}]}
CUTS_UM = {1: +12.0, 2: -10.0}  # where each tool cuts before any correction


class PollingCnc:
    """Two tools' totals (0.1 um) and what the CNC settled last for each."""

    def __init__(self, port: int) -> None:
        self.client = ModbusTcpClient("127.0.0.1", port=port, retries=0)
        self.client.connect()
        self.total = {1: 0, 2: 0}
        self.settled: dict[int, int | None] = {1: None, 2: None}
        self.applied: dict[int, list[int]] = {1: [], 2: []}

    def call(self, tool: int) -> None:
        """The subroutine called for ``tool``: settle its request, report its total."""
        regs = self.client.read_holding_registers(0, count=ENTRY_BLOCK_BASE, device_id=1)
        assert not regs.isError(), regs
        mirror = RegisterBank()
        mirror.write_words(0, regs.registers)
        result, total, seq = settle_request(mirror, self.total[tool], self.settled[tool], tool)
        if seq is not None:
            if total != self.total[tool]:
                self.applied[tool].append(total - self.total[tool])
            self.total[tool], self.settled[tool] = total, seq
        out = RegisterBank()
        write_report(out, self.settled[tool] or 0, result if seq is not None else Result.NONE,
                     self.total[tool], tool)
        tool_at = BY_NAME["cnc_tool"].address
        first = BY_NAME[REPORT[0]].address
        assert not self.client.write_register(tool_at, tool, device_id=1).isError()
        block = out.words(first, BY_NAME["cnc_check"].address - first + 1)
        assert not self.client.write_registers(first, block, device_id=1).isError()

    def cut_mm(self, tool: int) -> float:
        return (CUTS_UM[tool] + self.total[tool] * UM_PER_UNIT) / 1000.0


def test_two_tools_each_corrected_through_its_own_requests(tmp_path) -> None:
    # The service judges every frame: the frames of a part still queued when its offset is
    # applied were cut before it (dead_time_s skips them).
    settings = make_settings(
        tmp_path, plc={"source": "pull", "ack_timeout_s": 1.5},
        compensation={"nominal_mm": 30.0, "shadow": False, "law": "window", "gain": 0.7,
                      "window": 3, "deadband_mm": 0.002, "dead_time_measurements": 6,
                      "dead_time_s": 1.0, "max_step_mm": 0.01, "max_total_mm": 0.05,
                      "tol_upper_mm": 0.02, "tol_lower_mm": -0.02})
    gauge, _ = build(settings, Children())
    with TestClient(create_app(gauge)) as client:
        r = client.post("/api/v1/jobs", headers={"X-API-Key": TECHNICIAN},
                        json={"document": JOB, "activate": True})
        assert r.status_code == 201, r.text
        cnc = PollingCnc(gauge.modbus.port)
        try:
            for tool in (1, 2):  # the first calls: each tool's total, before any offset
                cnc.call(tool)
            for _ in range(10):  # parts: the journal by tool 1, then the seat by tool 2
                for feature in JOB["features"]:
                    t = feature["tool"]
                    gauge.camera.diameter_mm = feature["nominal_mm"] + cnc.cut_mm(t)
                    time.sleep(0.8)
                    cnc.call(t)
            # Once every offset is settled (the CNC reports, the settlers read it) the log's
            # applied offsets add up to each tool's total. A loaded machine settles an offset
            # left uncertain later: wait for it, however long it takes.
            def settled() -> dict | None:
                for t in (1, 2):
                    cnc.call(t)
                got = client.get("/api/v1/status").json()["compensation"]
                return got if all(t["pending_seq"] is None and t["state"] == "active"
                                  for t in got["entries"]) else None

            status = until(settled, "every offset of both tools settled", step_s=0.5)
            log = client.get("/api/v1/compensation/log", params={"limit": 2000}).json()
            # Every reader shows each tool's own cumulative offset, none the one channel's.
            mirror = RegisterBank()  # a read takes 125 registers at most: two
            mirror.write_words(0, cnc.client.read_holding_registers(
                0, count=ENTRY_BLOCK_BASE, device_id=1).registers)
            mirror.write_words(ENTRY_BLOCK_BASE, cnc.client.read_holding_registers(
                ENTRY_BLOCK_BASE, count=3 * ENTRY_BLOCK_WORDS, device_id=1).registers)
            metrics = client.get("/metrics").text
            plant = OpcUaValues(gauge.feed, gauge.compensation, gauge.camera,
                                gauge.writer).values()
        finally:
            cnc.client.close()
    status_tools = {t["tool"]: t for t in status["entries"]}
    assert status["cumulative_offset_mm"] is None and plant["CumulativeOffset"] is None
    assert mirror.get("cumulative_offset") == NO_VALUE == mirror.get("proposed_offset")
    assert mirror.get("entry3_tool") == 0
    for k, t in ((1, 1), (2, 2)):
        units = cnc.total[t]  # what the CNC applied, from a total of 0
        assert units != 0
        assert mirror.get(f"entry{k}_tool") == t and mirror.get(f"entry{k}_number") == 0
        assert mirror.get(f"entry{k}_cumulative") == units, (t, units)
        assert round(status_tools[t]["cumulative_offset_mm"] * 1e4) == units
        assert round(plant["Tools"][t]["CumulativeOffset"] * 1e4) == units
        line = f'shaftgauge_cumulative_offset_mm{{entry="",tool="{t}"}} '
        value = next(x for x in metrics.splitlines() if x.startswith(line))
        assert round(float(value.split()[-1]) * 1e4) == units, value
    assert [t["tool"] for t in status["entries"]] == [1, 2]
    for t in (1, 2):
        assert cnc.applied[t], f"tool {t}: nothing applied ({status})"
        # Corrected towards its own nominal: the cut is within the dead band's reach.
        assert abs(cnc.cut_mm(t)) < 0.006, (t, cnc.cut_mm(t), cnc.applied)
        applied = [row for row in log["items"] if row["kind"] == "applied"
                   and row["tool"] == t]
        logged = sum(round(row["offset_mm"] * 1000 / UM_PER_UNIT) for row in applied)
        assert logged == cnc.total[t], (t, logged, cnc.total)
    assert not [row for row in log["items"] if row["kind"] == "applied"
                and row["tool"] not in (1, 2)]
