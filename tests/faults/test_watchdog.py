"""The CNC's link under every reader at once: a Modbus client reads the heartbeat every 100 ms,
as a CNC's watchdog does, while the service streams its archive of a million rows as AQDEF,
refuses six JPEG "scan bombs" and serves three OPC UA clients asking for far more than its
limits (the second outside probe: one export stood the heartbeat still for 16.7 s, three for
19.7; the CNC's watchdog trips at 3 s).

It times the link, so it is marked ``timed``: ``make speed`` runs it alone (beside the
suite's other tests the machine's own load would be measured). ``SHAFTGAUGE_WATCHDOG_ROWS``
sets the archive's size.
"""

from __future__ import annotations

import asyncio
import json
import os
import sqlite3
import threading
import time
from pathlib import Path

import cv2
import httpx
import numpy as np
import pytest
from asyncua import Client, ua
from pymodbus.client import ModbusTcpClient

from calib_store.compensation_log import MEASUREMENT_COLUMNS, CompensationLog
from drivers.plc.registers import BY_NAME
from service.runtime.feed import SEQ_KEY
from tests.e2e.conftest import TECH_KEY, start_service, stop_service, wait_ready
from tests.integration.conftest import free_port

pytestmark = pytest.mark.timed

ROWS = int(os.environ.get("SHAFTGAUGE_WATCHDOG_ROWS", "1000000"))
MAX_GAP_S = 1.0


def archive(store: Path, rows: int) -> None:
    """A store whose archive holds ``rows`` measurements, one a second, as 11.6 days of the
    default ``store.archive_hz`` leave it."""
    CompensationLog(store).close()  # its schema
    t0 = time.time() - rows
    columns = ", ".join(MEASUREMENT_COLUMNS)
    marks = ", ".join("?" for _ in MEASUREMENT_COLUMNS)
    with sqlite3.connect(store) as db:
        db.executemany(f"INSERT INTO measurements ({columns}) VALUES ({marks})", (
            (i, t0 + i, "ok", 30.0 + 1e-4 * (i % 50), 0.002, 30.0 + 1e-4 * (i % 40), None,
             1, 1, 30.0, -0.02, 0.02, None, None, None) for i in range(1, rows + 1)))
        db.execute("INSERT OR REPLACE INTO gauge_values (key, value) VALUES (?, ?)",
                   (SEQ_KEY, json.dumps(rows + 1)))


class Watchdog:
    """Reads the heartbeat every 100 ms in a thread of its own; the longest time between two
    answers, and whether the heartbeat went on counting."""

    def __init__(self, port: int) -> None:
        self.port, self.gaps, self.beats = port, [], set()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        address = BY_NAME["heartbeat"].address
        with ModbusTcpClient("127.0.0.1", port=self.port, timeout=3, retries=0) as c:
            last = time.monotonic()
            while not self._stop.wait(0.1):
                r = c.read_holding_registers(address, count=1, device_id=1)
                now = time.monotonic()
                if not r.isError():
                    self.gaps.append(now - last)
                    self.beats.add(r.registers[0])
                    last = now

    def close(self) -> float:
        """Stop; the longest gap, s."""
        self._stop.set()
        self._thread.join(10)
        return max(self.gaps)


def scan_bomb() -> bytes:
    """A progressive JPEG of the camera's size whose last scan's header is sent again and
    again: about 10 bytes a scan, a hundred thousand scans."""
    image = np.random.default_rng(5).integers(0, 255, (1024, 1376), np.uint8)
    data = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_PROGRESSIVE, 1])[1].tobytes()
    last = data.rindex(b"\xff\xda")
    header = data[last:last + 2 + int.from_bytes(data[last + 2:last + 4], "big")]
    return data[:-2] + header * 100_000 + data[-2:]


async def greedy_opcua_client(url: str) -> int:
    """Ten subscriptions of a thousand items at 1 ms, as far as the server lets it; the items
    it was granted."""
    granted = 0
    async with Client(url, timeout=30) as client:
        node = client.get_node(ua.NodeId(ua.ObjectIds.Server_ServerStatus_CurrentTime))
        for _ in range(10):
            try:
                sub = await client.create_subscription(1, None)
            except ua.UaError:
                break
            made = await sub.subscribe_data_change([node] * 1000, sampling_interval=1)
            granted += sum(1 for h in made if not isinstance(h, ua.StatusCode))
        await asyncio.sleep(10)
    return granted


def test_the_cncs_heartbeat_keeps_its_timing_under_every_reader(tmp_path: Path) -> None:
    data = tmp_path / "data"
    data.mkdir()
    archive(data / "gauge.db", ROWS)
    opcua = free_port()
    svc = start_service(tmp_path, data=data, opcua_port=opcua)
    try:
        assert wait_ready(svc, 120)
        dog = Watchdog(svc.modbus_port)
        sid = httpx.post(svc.url + "/api/v1/calibration-sessions", json={},
                         headers={"X-API-Key": TECH_KEY}, timeout=30).json()["id"]
        bomb, answers = scan_bomb(), []

        def upload() -> None:
            answers.append(httpx.post(
                f"{svc.url}/api/v1/calibration-sessions/{sid}/images/view", content=bomb,
                headers={"X-API-Key": TECH_KEY, "content-type": "image/jpeg"},
                timeout=120).status_code)

        exported = {}

        def export() -> None:
            with httpx.stream("GET", svc.url + "/api/v1/export/aqdef", timeout=600) as r:
                exported["status"] = r.status_code
                exported["bytes"] = sum(len(b) for b in r.iter_bytes())
                exported["values"] = int(r.headers.get("x-values", -1))

        others = {}

        def opcua_clients() -> None:
            async def three() -> list:
                return await asyncio.gather(*(greedy_opcua_client(
                    f"opc.tcp://127.0.0.1:{opcua}/") for _ in range(3)), return_exceptions=True)
            others["opcua"] = asyncio.run(three())

        threads = [threading.Thread(target=f) for f in
                   (export, opcua_clients, *([upload] * 6))]
        for t in threads:
            t.start()
        for t in threads:
            t.join(900)
        late = httpx.get(svc.url + "/api/v1/export/aqdef", timeout=60)  # the export is done
        gap = dog.close()
        print(f"\nFIGURES {ROWS} rows exported ({exported.get('bytes', 0) / 1e6:.0f} MB), "
              f"6 scan bombs {sorted(answers)}, OPC UA {others.get('opcua')}: longest gap "
              f"between heartbeat reads {gap:.2f} s over {len(dog.gaps)} reads, "
              f"{len(dog.beats)} heartbeat values")
        assert exported["status"] == 200 and exported["values"] >= ROWS, exported
        assert answers == [422] * 6, answers
        assert all(isinstance(n, int) and n <= 1000 for n in others["opcua"]), others
        assert late.status_code == 200
        assert gap <= MAX_GAP_S, gap
        assert len(dog.beats) >= 3
    finally:
        stop_service(svc)
