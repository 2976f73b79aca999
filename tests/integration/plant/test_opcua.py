"""The OPC UA server with asyncua's own client on a free local port: anonymous users read and
subscribe, technicians call the methods, a wrong password is refused."""

from __future__ import annotations

import asyncio
import math
from pathlib import Path

import pytest
from asyncua import Client, ua

from service.config import OpcUaSettings
from service.plant.opcua import GaugeView, OpcUaServer
from tests.integration.conftest import free_port


class FakeGauge:
    """The gauge's side of the server: values that change, methods that count."""

    def __init__(self) -> None:
        self.values = {"Diameter": 36.5, "Uncertainty": 0.002, "Status": "ok",
                       "MeasurementSeq": 1, "CalibrationId": 3, "State": "idle",
                       "CumulativeOffset": 0.0, "InTolerance": True, "Deviation": None}
        self.resets: list[str] = []

    async def measure_now(self) -> tuple[float | None, str]:
        return 36.501, "ok"

    async def reset(self, who: str) -> str:
        self.resets.append(who)
        return "reset"


@pytest.fixture
async def served(tmp_path: Path):
    gauge = FakeGauge()
    port = free_port()
    server = OpcUaServer(OpcUaSettings(port=port, technicians={"anna": "s3cret"}),
                         GaugeView(lambda: gauge.values, gauge.measure_now, gauge.reset,
                                   serial_number="sim-1"), tmp_path / "opcua")
    task = asyncio.create_task(server.run())
    for _ in range(200):
        if server.server is not None or server.problem:
            break
        await asyncio.sleep(0.05)
    assert server.server is not None, server.problem
    yield server, gauge, f"opc.tcp://127.0.0.1:{port}/"
    task.cancel()
    await asyncio.gather(task, return_exceptions=True)
    await server.close()


async def _node(client: Client, *path: str):
    idx = await client.get_namespace_index("urn:shaftgauge")
    return await client.nodes.objects.get_child([f"{idx}:{p}" for p in path])


async def test_an_anonymous_client_reads_and_subscribes_but_cannot_call(served) -> None:
    server, gauge, url = served
    async with Client(url) as client:
        diameter = await _node(client, "Shaftgauge", "Monitoring", "Diameter")
        assert await diameter.read_value() == pytest.approx(36.5)
        assert math.isnan(await (await _node(client, "Shaftgauge", "Monitoring",
                                             "Deviation")).read_value())
        serial = await _node(client, "Shaftgauge", "Identification", "SerialNumber")
        assert await serial.read_value() == "sim-1"

        seen: list[float] = []

        class Handler:
            def datachange_notification(self, node, val, data) -> None:
                seen.append(val)

        sub = await client.create_subscription(50, Handler())
        await sub.subscribe_data_change(diameter)
        gauge.values["Diameter"] = 36.512
        for _ in range(100):
            if 36.512 in seen:
                break
            await asyncio.sleep(0.05)
        assert 36.512 in seen, seen

        gauge_obj = await _node(client, "Shaftgauge")
        idx = await client.get_namespace_index("urn:shaftgauge")
        with pytest.raises(ua.UaStatusCodeError) as err:
            await gauge_obj.call_method(f"{idx}:ResetCompensation")
        assert "BadUserAccessDenied" in type(err.value).__name__ + str(err.value)
        with pytest.raises(ua.UaStatusCodeError):
            await diameter.write_value(1.0)
    assert gauge.resets == []
    assert server.calls["ResetCompensation"] == 0


async def test_a_technician_calls_the_methods(served) -> None:
    _, gauge, url = served
    client = Client(url)
    client.set_user("anna")
    client.set_password("s3cret")
    async with client:
        gauge_obj = await _node(client, "Shaftgauge")
        idx = await client.get_namespace_index("urn:shaftgauge")
        diameter, status = await gauge_obj.call_method(f"{idx}:MeasureNow")
        assert (diameter, status) == (pytest.approx(36.501), "ok")
        assert await gauge_obj.call_method(f"{idx}:ResetCompensation") == "reset"
    assert gauge.resets == ["opcua:technician"]


async def test_a_wrong_password_is_refused(served) -> None:
    _, _, url = served
    client = Client(url)
    client.set_user("anna")
    client.set_password("wrong")
    with pytest.raises(ua.UaStatusCodeError) as err:
        async with client:
            pass
    assert "BadUserAccessDenied" in type(err.value).__name__ + str(err.value)


async def test_a_port_in_use_is_a_problem_not_a_crash(tmp_path: Path) -> None:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        server = OpcUaServer(OpcUaSettings(port=port), GaugeView(
            dict, FakeGauge().measure_now, FakeGauge().reset), tmp_path)
        await server.run()
    assert server.server is None
    assert f"127.0.0.1:{port} did not start" in server.problem
    assert server.problems()[0][0] == "opcua_down"
