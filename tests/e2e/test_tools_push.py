"""A job of two tools through ``shaftgauge serve`` and its simulated PLC over the push
handshake: the seat, cut large, moves only tool 2's block of the CNC's registers (offset
number 2's); tool 1's (the first) stays as it was."""

from __future__ import annotations

import json
import time

import httpx

from drivers.sim.control import control
from tests.e2e.conftest import TECH_KEY, start_service, stop_service, wait_ready

JOB = {"part_number": "SH-2T", "name": "two tools", "features": [
    {"number": 1, "name": "journal", "nominal_mm": 30.0, "tol_upper_mm": 0.05,
     "tol_lower_mm": -0.05, "tool": 1},
    {"number": 2, "name": "seat", "nominal_mm": 25.0, "tol_upper_mm": 0.05,
     "tol_lower_mm": -0.05, "tool": 2}]}


def applied(svc) -> list[tuple[int | None, int]]:
    log = svc.data / "sim-plc.log"
    events = [json.loads(line) for line in log.read_text().splitlines()] if log.exists() \
        else []
    return [(e.get("offset", 1), e["value_units"]) for e in events if e["event"] == "applied"]


def test_the_seat_cut_large_moves_only_its_tools_block(tmp_path) -> None:
    svc = start_service(tmp_path)
    try:
        assert wait_ready(svc)
        r = httpx.post(svc.url + "/api/v1/jobs", headers={"X-API-Key": TECH_KEY},
                       json={"document": JOB, "activate": True}, timeout=10)
        assert r.status_code == 201, r.text
        assert control(svc.control_port, {"set": {"diameter_mm": 25.012}})["ok"]
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and not applied(svc):
            time.sleep(0.5)
        status = svc.get("/api/v1/status").json()["compensation"]
        tools = {t["tool"]: t for t in status["entries"]}
    finally:
        stop_service(svc)
    moved = applied(svc)
    assert moved and {tool for tool, _ in moved} == {2}, moved
    assert all(units < 0 for _, units in moved), moved  # the seat is large: cut smaller
    assert tools[2]["cnc_total_mm"] < 0 and tools[2]["writes_blocked"] is None, tools
    assert tools[1]["cnc_total_mm"] == 0.0 and tools[1]["offset_seq"] == 0, tools
