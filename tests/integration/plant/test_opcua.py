"""The OPC UA server with asyncua's own client on a free local port: anonymous users read and
subscribe, technicians call the methods, a wrong password is refused."""

from __future__ import annotations

import asyncio
import math
from pathlib import Path

import pytest
from asyncua import Client, ua
from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256

from service.config import OpcUaSettings
from service.plant.opcua import LOGIN_FAILURES, GaugeView, OpcUaServer
from tests.integration.conftest import free_port
from tests.waiting import DEADLINE_S, until_async


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


async def _running(tmp_path: Path, none_security: bool):
    """A server for a ``FakeGauge`` on a free port, until the test is done."""
    gauge = FakeGauge()
    port = free_port()
    server = OpcUaServer(OpcUaSettings(port=port, technicians={"anna": "s3cret"},
                                       none_security=none_security),
                         GaugeView(lambda: gauge.values, gauge.measure_now, gauge.reset,
                                   serial_number="sim-1"), tmp_path / "opcua")
    task = asyncio.create_task(server.run())
    await asyncio.wait_for(server.started.wait(), DEADLINE_S)
    assert server.server is not None, server.problem
    yield server, gauge, f"opc.tcp://127.0.0.1:{port}/"
    task.cancel()
    await asyncio.gather(task, return_exceptions=True)
    await server.close()


@pytest.fixture
async def served(tmp_path: Path):
    """As the embedded default runs it: the unsecured endpoint beside the secure one."""
    async for running in _running(tmp_path, none_security=True):
        yield running


async def _node(client: Client, *path: str):
    idx = await client.get_namespace_index("urn:shaftgauge")
    return await client.nodes.objects.get_child([f"{idx}:{p}" for p in path])


async def _made(client: Client, *path: str):
    """The node at ``path`` once the server has made it (objects of the job come as the
    server refreshes)."""
    async def node():
        try:
            return await _node(client, *path)
        except ua.UaStatusCodeError:
            return None

    return await until_async(node, f"{path[-1]} made")


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
        await until_async(lambda: 36.512 in seen, f"the new diameter notified ({seen})")

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


async def test_a_wrong_password_is_logged_naming_the_user_not_the_password(served,
                                                                          caplog) -> None:
    server, _, url = served
    client = Client(url)
    client.set_user("anna")
    client.set_password("guess-0123")
    with caplog.at_level("WARNING", logger="shaftgauge.opcua"), \
            pytest.raises(ua.UaStatusCodeError):
        async with client:
            pass
    said = [r.getMessage() for r in caplog.records if r.name == "shaftgauge.opcua"]
    assert any("'anna'" in line and "wrong password" in line for line in said), said
    assert not any("guess-0123" in line for line in caplog.text.splitlines())
    assert server.status()["refused_logins"] == 1


async def test_guessing_a_password_is_held_after_a_few_tries(served) -> None:
    """About 300 guesses a second were possible; now a name is held after LOGIN_FAILURES
    wrong passwords within a minute, and then even the right one is refused."""
    server, _, url = served

    async def login(password: str) -> bool:
        client = Client(url)
        client.set_user("anna")
        client.set_password(password)
        try:
            async with client:
                return True
        except ua.UaStatusCodeError:
            return False

    results = [await login(f"guess-{i}") for i in range(LOGIN_FAILURES)]
    assert results == [False] * LOGIN_FAILURES
    assert not await login("s3cret")
    assert "wait" in server.status()["last_refused_login"]


def test_the_server_key_is_readable_by_the_service_alone(served) -> None:
    server, _, _ = served
    key = server.certificate_dir / "server-key.pem"
    assert key.stat().st_mode & 0o777 == 0o600


async def _client_certificate(where: Path, uri: str) -> tuple[Path, Path]:
    from asyncua.crypto.cert_gen import setup_self_signed_certificate
    from cryptography.x509.oid import ExtendedKeyUsageOID

    key, cert = where / "client-key.pem", where / "client.der"
    await setup_self_signed_certificate(key, cert, uri, "plant-scada",
                                        [ExtendedKeyUsageOID.CLIENT_AUTH],
                                        {"commonName": "plant-scada"})
    return key, cert


async def _secure_client(url: str, key: Path, cert: Path, uri: str) -> Client:
    client = Client(url)
    client.application_uri = uri
    await client.set_security(SecurityPolicyBasic256Sha256, str(cert), str(key),
                              mode=ua.MessageSecurityMode.SignAndEncrypt)
    return client


@pytest.fixture
async def installed(tmp_path: Path):
    """The server as an installation runs it: no unsecured endpoint."""
    async for running in _running(tmp_path, none_security=False):
        yield running


async def test_an_installation_offers_no_unsecured_endpoint(installed) -> None:
    server, _, url = installed
    endpoints = await Client(url).connect_and_get_server_endpoints()  # discovery: answered
    assert endpoints and {e.SecurityMode for e in endpoints} == {
        ua.MessageSecurityMode.SignAndEncrypt}
    with pytest.raises(ua.UaError, match="No matching endpoints"):
        async with Client(url):  # an unsecured session: there is no endpoint for it
            pass
    assert server.status()["none_security"] is False


async def test_an_untrusted_client_certificate_is_refused_until_trusted(installed,
                                                                       tmp_path: Path,
                                                                       caplog) -> None:
    server, gauge, url = installed
    uri = "urn:plant:scada"
    key, cert = await _client_certificate(tmp_path, uri)
    client = await _secure_client(url, key, cert, uri)
    with caplog.at_level("WARNING", logger="shaftgauge.opcua"), \
            pytest.raises(ua.UaStatusCodeError) as err:
        async with client:
            pass
    assert "BadCertificateUntrusted" in type(err.value).__name__ + str(err.value)
    assert server.status()["refused_certificates"] == 1
    refused = server.status()["last_refused_certificate"]
    assert "urn:plant:scada" in refused and "BadCertificateUntrusted" in refused
    assert refused in caplog.text and str(server.trusted_dir) in refused

    (server.trusted_dir / "plant-scada.der").write_bytes(cert.read_bytes())
    client = await _secure_client(url, key, cert, uri)
    client.set_user("anna")
    client.set_password("s3cret")
    async with client:  # trusted now: signed, encrypted, and the technician's methods
        gauge_obj = await _node(client, "Shaftgauge")
        idx = await client.get_namespace_index("urn:shaftgauge")
        assert await gauge_obj.call_method(f"{idx}:ResetCompensation") == "reset"
    assert gauge.resets == ["opcua:technician"]


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


async def test_each_feature_of_the_job_is_a_characteristic(served) -> None:
    """OPC 40210's names: CharacteristicIdentifier, Nominal, the tolerances, ResultValue and
    ResultEvaluation; a feature of a job no longer in force stays, marked not in the job."""
    _, gauge, url = served
    gauge.values["Characteristics"] = {
        1: {"CharacteristicIdentifier": 1, "Name": "journal", "Nominal": 30.0,
            "LowerTolerance": -0.015, "UpperTolerance": 0.015, "ResultValue": 30.004,
            "ResultEvaluation": "InTolerance"},
        2: {"CharacteristicIdentifier": 2, "Name": "seat", "Nominal": 25.0,
            "LowerTolerance": -0.01, "UpperTolerance": 0.01, "ResultValue": None,
            "ResultEvaluation": "NotMeasured"}}
    async with Client(url) as client:
        seat = await _made(client, "Shaftgauge", "Characteristics", "Characteristic2")
        value = await (await _node(client, "Shaftgauge", "Characteristics",
                                   "Characteristic1", "ResultValue")).read_value()
        assert value == pytest.approx(30.004)
        idx = await client.get_namespace_index("urn:shaftgauge")
        assert await (await seat.get_child(f"{idx}:Name")).read_value() == "seat"
        assert math.isnan(await (await seat.get_child(f"{idx}:ResultValue")).read_value())
        assert await (await seat.get_child(f"{idx}:InJob")).read_value() is True
        del gauge.values["Characteristics"][2]  # another job
        in_job = await seat.get_child(f"{idx}:InJob")

        async def out_of_the_job() -> bool:
            return await in_job.read_value() is False

        await until_async(out_of_the_job, "Characteristic2 marked not in the job")


async def test_each_tool_of_the_job_shows_its_own_offsets(served) -> None:
    """A job of two tools and an offset entry: ``Tools/Tool<t>`` by T number,
    ``Tool<t>_<n>`` for its offset number n, each with its cumulative offset; the gauge-wide
    one has no value."""
    _, gauge, url = served
    gauge.values.update(CumulativeOffset=None, Tools={
        1: {"ToolNumber": 1, "State": "active", "CumulativeOffset": 0.0012,
            "LastOffset": 0.0004},
        12: {"ToolNumber": 12, "State": "alarm", "CumulativeOffset": -0.0031,
             "LastOffset": None},
        "12_10012": {"ToolNumber": 12, "OffsetNumber": 10012, "State": "active",
                     "CumulativeOffset": 0.0025, "LastOffset": 0.0005}})
    async with Client(url) as client:
        t12 = await _made(client, "Shaftgauge", "Tools", "Tool12")
        idx = await client.get_namespace_index("urn:shaftgauge")
        assert await (await t12.get_child(f"{idx}:CumulativeOffset")).read_value() \
            == pytest.approx(-0.0031)
        assert await (await t12.get_child(f"{idx}:State")).read_value() == "alarm"
        assert math.isnan(await (await t12.get_child(f"{idx}:LastOffset")).read_value())
        t1 = await _node(client, "Shaftgauge", "Tools", "Tool1", "CumulativeOffset")
        assert await t1.read_value() == pytest.approx(0.0012)
        pin = await _made(client, "Shaftgauge", "Tools", "Tool12_10012")
        assert await (await pin.get_child(f"{idx}:OffsetNumber")).read_value() == 10012
        assert await (await pin.get_child(f"{idx}:CumulativeOffset")).read_value() \
            == pytest.approx(0.0025)
        whole = await _node(client, "Shaftgauge", "Compensation", "CumulativeOffset")
        assert math.isnan(await whole.read_value())


async def test_what_anonymous_clients_may_ask_is_bounded(tmp_path: Path) -> None:
    """The second outside probe: three anonymous clients of ten subscriptions of a thousand
    items at 1 ms slowed the CNC's Modbus reads to 430 ms, and 200 sessions were taken. Past
    the limits a client is refused (connections, subscriptions, items); a shorter interval
    than the least is revised up."""
    gauge = FakeGauge()
    port = free_port()
    server = OpcUaServer(OpcUaSettings(port=port, none_security=True, max_connections=2,
                                       max_subscriptions=6, max_monitored_items=8,
                                       min_interval_ms=200.0),
                         GaugeView(lambda: gauge.values, gauge.measure_now, gauge.reset),
                         tmp_path / "opcua")
    task = asyncio.create_task(server.run())
    await asyncio.wait_for(server.started.wait(), DEADLINE_S)
    url = f"opc.tcp://127.0.0.1:{port}/"
    try:
        async with Client(url) as client:
            diameter = await _node(client, "Shaftgauge", "Monitoring", "Diameter")
            subs = [await client.create_subscription(1, None) for _ in range(5)]
            with pytest.raises(ua.UaStatusCodeError, match="BadTooManySubscriptions"):
                await client.create_subscription(1, None)  # a sixth in one session
            granted = server.server.iserver.subscription_service.subscriptions
            assert {s.data.RevisedPublishingInterval for s in granted.values()} == {200.0}
            made = await subs[0].subscribe_data_change([diameter] * 12, sampling_interval=1)
            refused = [h for h in made if isinstance(h, ua.StatusCode)]
            assert len(made) - len(refused) == 8 and len(refused) == 4, made
            assert all(r.value == ua.StatusCodes.BadTooManyMonitoredItems for r in refused)
            async with Client(url):
                with pytest.raises((OSError, ua.UaError, asyncio.TimeoutError)):
                    async with Client(url, timeout=5):  # a third client
                        pass
    finally:
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)
        await server.close()
