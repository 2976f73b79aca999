"""Modbus/TCP Security with a PKI the test makes: the gauge's server takes a client with a
certificate from its authority and refuses any other (counted, logged); the gauge writes
offsets to a CNC that speaks TLS, and a CNC it cannot verify gets none."""

from __future__ import annotations

import ssl

import pytest
from pymodbus.client import AsyncModbusTcpClient, AsyncModbusTlsClient
from pymodbus.exceptions import ModbusException

from drivers.plc.client import OffsetWriter, Outcome
from drivers.plc.registers import MAP_VERSION, RegisterBank, RegisterType, WordOrder, to_words
from drivers.plc.server import GaugeModbusServer
from drivers.plc.sim import SimPlc
from drivers.plc.tls import TlsFiles, client_context, server_context
from tests.integration.pki import Authority


@pytest.fixture
def pki(tmp_path):
    plant, stranger = Authority(tmp_path / "plant", "plant-ca"), \
        Authority(tmp_path / "stranger", "stranger-ca")
    return plant, stranger


@pytest.fixture
async def gauge_tls(pki):
    plant, _ = pki
    writes: list = []
    server = GaugeModbusServer(RegisterBank(), port=0,
                               on_write=lambda entries, peer: writes.append((entries, peer)),
                               tls=plant.issue("gauge", server=True))
    await server.start()
    yield server, writes
    await server.stop()


async def _read_version(port: int, ctx: ssl.SSLContext) -> int | None:
    """The map version (register 2) read over TLS, or None when the server would not talk."""
    client = AsyncModbusTlsClient("127.0.0.1", sslctx=ctx, port=port, timeout=2, retries=0,
                                  reconnect_delay=0)
    try:
        if not await client.connect():
            return None
        rr = await client.read_holding_registers(2, count=1, device_id=1)
        return None if rr.isError() else rr.registers[0]
    except (ModbusException, OSError):
        return None
    finally:
        client.close()


async def test_a_client_of_the_plants_authority_reads_and_writes(gauge_tls, pki) -> None:
    server, writes = gauge_tls
    plant, _ = pki
    ctx = client_context(plant.issue("cnc-7", server=False))
    assert await _read_version(server.port, ctx) == MAP_VERSION
    client = AsyncModbusTlsClient("127.0.0.1", sslctx=ctx, port=server.port, retries=0)
    await client.connect()
    nominal = to_words(250_000, RegisterType.I32, WordOrder.BIG)  # 25 mm
    rr = await client.write_registers(14, nominal, device_id=1)
    client.close()
    assert not rr.isError()
    assert writes and writes[0][1] == "127.0.0.1 (cnc-7)"  # the write's peer, by its name
    assert server.tls_refusals.count == 0


async def test_a_client_without_a_valid_certificate_is_refused(gauge_tls, pki) -> None:
    server, _ = gauge_tls
    plant, stranger = pki
    # trusts the gauge's authority, but its own is not the gauge's
    foreign = client_context(stranger.issue("intruder", server=False, trusts=plant))
    assert await _read_version(server.port, foreign) is None
    anonymous = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
    anonymous.load_verify_locations(cafile=plant.cafile)  # no certificate of its own
    assert await _read_version(server.port, anonymous) is None
    plain = AsyncModbusTcpClient("127.0.0.1", port=server.port, timeout=2, retries=0,
                                 reconnect_delay=0)
    await plain.connect()  # TCP connects; its Modbus frame is no TLS handshake
    with pytest.raises(ModbusException):
        await plain.read_holding_registers(2, count=1, device_id=1)
    plain.close()
    assert set(server.tls_refusals.reasons) == {
        "CERTIFICATE_VERIFY_FAILED", "PEER_DID_NOT_RETURN_A_CERTIFICATE", "WRONG_VERSION_NUMBER"}
    assert "does not speak TLS" in server.tls_refusals.last
    assert server.requests == 0  # nothing reached the registers


async def test_offsets_reach_a_cnc_over_tls_and_none_reach_one_it_cannot_verify(pki) -> None:
    plant, stranger = pki
    cnc = SimPlc(port=0, sslctx=server_context(plant.issue("cnc", server=True)))
    await cnc.start()
    try:
        writer = OffsetWriter("127.0.0.1", cnc.port,
                              sslctx=client_context(plant.issue("gauge", server=False)))
        r = await writer.write_offset(-0.0042, 1)
        await writer.close()
        assert r.outcome is Outcome.APPLIED and "verified" in r.message, r
        assert cnc.total_units == -42 and [e["event"] for e in cnc.events] == [
            "write", "applied"]
        doubtful = OffsetWriter("127.0.0.1", cnc.port, reconnect_initial_s=0.05,
                                sslctx=client_context(plant.issue(
                                    "gauge-2", server=False, trusts=stranger)))  # cannot
        # verify the CNC: a certificate from an authority it does not trust
        r = await doubtful.write_offset(0.003, 2)
        await doubtful.close()
        assert r.outcome is Outcome.NOT_APPLIED and not doubtful.connected, r
        assert cnc.total_units == -42  # nothing more
    finally:
        await cnc.stop()


def test_a_missing_file_is_named(tmp_path) -> None:
    files = TlsFiles(tmp_path / "gauge.pem", tmp_path / "gauge.key", tmp_path / "ca.pem")
    with pytest.raises(ValueError, match=r"modbus.tls.certfile .*gauge.pem: no such file"):
        GaugeModbusServer(RegisterBank(), port=0, tls=files)
