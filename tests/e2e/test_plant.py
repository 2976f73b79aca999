"""The embedded default on the plant's systems: Mosquitto (Debian's) receives measurements,
decisions and the state (its last will when the gauge is killed), an OPC UA client reads the
diameter over opc.tcp, and the AQDEF export returns K0001 lines."""

from __future__ import annotations

import asyncio
import json
import os
import signal
import subprocess
import time
from pathlib import Path

from asyncua import Client

from tests.e2e.conftest import start_service, stop_service, wait_opcua, wait_ready
from tests.integration.conftest import free_port
from tests.integration.plant.conftest import Mosquitto


def sub(port: int, topic: str, count: int, timeout_s: int = 30) -> list[str]:
    """``mosquitto_sub`` as a plant engineer would run it: ``count`` messages' payloads."""
    done = subprocess.run(["mosquitto_sub", "-h", "127.0.0.1", "-p", str(port), "-t", topic,
                           "-C", str(count), "-W", str(timeout_s)], capture_output=True,
                          text=True, timeout=timeout_s + 10)
    return done.stdout.splitlines()


async def read_diameter(url: str, *path: str) -> float:
    async with Client(url) as client:
        idx = await client.get_namespace_index("urn:shaftgauge")
        node = await client.nodes.objects.get_child(
            [f"{idx}:{p}" for p in ("Shaftgauge", *(path or ("Monitoring", "Diameter")))])
        return await node.read_value()


def test_the_embedded_default_reports_to_mqtt_opcua_and_aqdef(tmp_path: Path) -> None:
    broker = Mosquitto(tmp_path / "broker").start()
    opcua = free_port()
    svc = start_service(tmp_path, diameter=30.0, opcua_port=opcua, env={
        "SHAFTGAUGE_MQTT__HOST": "127.0.0.1", "SHAFTGAUGE_MQTT__PORT": str(broker.port),
        "SHAFTGAUGE_MQTT__GAUGE_ID": "e2e-lathe"})
    try:
        assert wait_ready(svc)
        got = [json.loads(x) for x in sub(broker.port, "shaftgauge/+/measurement", 3)]
        assert len(got) == 3 and all(m["gauge_id"] == "e2e-lathe" for m in got)
        assert abs(got[-1]["diameter_mm"] - 30.0) < 0.02
        decision = json.loads(sub(broker.port, "shaftgauge/e2e-lathe/decision", 1)[0])
        assert decision["decision_seq"] >= 1 and decision["kind"]
        assert sub(broker.port, "shaftgauge/e2e-lathe/state", 1) == ["online"]  # retained

        ua = wait_opcua(svc)
        assert ua["running"], f"{ua}\n{svc.stderr()[-3000:]}"
        diameter = asyncio.run(read_diameter(f"opc.tcp://127.0.0.1:{opcua}"))
        assert abs(diameter - 30.0) < 0.02
        # The single feature is the job's characteristic 1 (OPC 40210's names).
        result = asyncio.run(read_diameter(f"opc.tcp://127.0.0.1:{opcua}", "Characteristics",
                                           "Characteristic1", "ResultValue"))
        assert abs(result - 30.0) < 0.02

        deadline, lines = time.monotonic() + 20, []
        while time.monotonic() < deadline and len(lines) < 2:
            r = svc.get("/api/v1/export/aqdef")
            assert r.status_code == 200
            lines = [x for x in r.text.splitlines() if x.startswith("K0001")]
            time.sleep(0.5)
        assert len(lines) >= 2 and abs(float(lines[-1].split()[1]) - 30.0) < 0.02

        plant = svc.get("/api/v1/status").json()["plant"]
        assert plant["mqtt"]["connected"] and plant["opcua"]["running"]
        os.killpg(svc.proc.pid, signal.SIGKILL)  # the gauge vanishes: the broker's last will
        svc.proc.wait(10)
        deadline, state = time.monotonic() + 30, []
        while time.monotonic() < deadline and state != ["offline"]:
            state = sub(broker.port, "shaftgauge/e2e-lathe/state", 1, 5)
        assert state == ["offline"]
    finally:
        stop_service(svc)
        broker.stop()
