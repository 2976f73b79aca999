"""The gauge's Modbus TCP server, polled over loopback by pymodbus and by mbpoll."""

from __future__ import annotations

import asyncio
import socket
import subprocess

import pytest
from pymodbus.client import AsyncModbusTcpClient
from pymodbus.pdu.file_message import FileRecord

from drivers.plc.registers import (
    MAP_VERSION,
    SIZE,
    RegisterBank,
    RegisterType,
    WordOrder,
    from_words,
)
from drivers.plc.server import GaugeModbusServer, run_heartbeat


@pytest.fixture
async def served():
    bank = RegisterBank()
    writes: list = []
    server = GaugeModbusServer(bank, port=0, on_write=lambda entries, _peer: writes.extend(entries))
    await server.start()
    client = AsyncModbusTcpClient("127.0.0.1", port=server.port, retries=0)
    await client.connect()
    yield bank, server, client, writes
    client.close()
    await server.stop()


async def test_client_reads_the_map_with_fc3_and_fc4(served) -> None:
    bank, _, client, _ = served
    bank.set_many({"diameter": 300_123, "measurement_seq": 42})
    for read in (client.read_holding_registers, client.read_input_registers):
        rr = await read(0, count=30, device_id=1)
        assert not rr.isError()
        assert rr.registers[:2] == [0x1234, 0x5678]
        assert from_words(rr.registers[6:8], RegisterType.I32, WordOrder.BIG) == 300_123
        assert from_words(rr.registers[10:12], RegisterType.U32, WordOrder.BIG) == 42


async def test_writes_reach_the_bank_and_the_service(served) -> None:
    bank, _, client, writes = served
    rr = await client.write_registers(14, [0x0004, 0x93E0, 0, 200, 0xFFFF, 0xFF38],
                                      device_id=1)
    assert not rr.isError()
    assert bank.get("nominal") == 300_000 and bank.get("tol_lower") == -200
    assert writes == [("nominal", 300_000), ("tol_upper", 200), ("tol_lower", -200)]


@pytest.mark.parametrize(("request_", "code"), [
    (("read_holding_registers", SIZE - 1, {"count": 2}), 2),  # beyond the map
    (("write_register", 4, {"value": 1}), 2),             # read-only
    (("write_register", 15, {"value": 1}), 2),            # half of a pair
    (("write_register", 20, {"value": 9}), 3),            # not a command code
    (("write_registers", 16, {"values": [0xFFFF, 0xFFFF]}), 3),  # negative upper tolerance
    (("read_coils", 0, {"count": 8}), 1),                 # coils are not served
])
async def test_bad_requests_get_modbus_exceptions(served, request_, code) -> None:
    bank, _, client, writes = served
    name, address, kw = request_
    before = bank.words(0, SIZE)
    rr = await getattr(client, name)(address, device_id=1, **kw)
    assert rr.isError() and rr.exception_code == code
    assert bank.words(0, SIZE) == before and writes == []


async def test_other_unit_ids_get_the_gateway_exception(served) -> None:
    _, _, client, _ = served
    rr = await client.read_holding_registers(0, count=2, device_id=9)
    assert rr.isError() and rr.exception_code == 0x0B


async def test_garbage_on_the_wire_does_not_stop_the_server(served) -> None:
    _, server, client, _ = served

    def junk() -> None:
        for payload in (b"\x00" * 3, b"\xff" * 300, b"\x00\x01\x00\x00\x00\x06\x01\x03\x00"):
            with socket.create_connection(("127.0.0.1", server.port), timeout=2) as s:
                s.sendall(payload)
    await asyncio.to_thread(junk)
    rr = await client.read_holding_registers(0, count=2, device_id=1)
    assert rr.registers == [0x1234, 0x5678]


async def test_little_endian_word_order() -> None:
    server = GaugeModbusServer(RegisterBank(WordOrder.LITTLE), port=0)
    await server.start()
    client = AsyncModbusTcpClient("127.0.0.1", port=server.port, retries=0)
    await client.connect()
    try:
        rr = await client.read_holding_registers(0, count=2, device_id=1)
        assert rr.registers == [0x5678, 0x1234]
    finally:
        client.close()
        await server.stop()


def mbpoll(port: int) -> list[int]:
    out = subprocess.run(["mbpoll", "-m", "tcp", "-a", "1", "-r", "1", "-c", "4", "-t",
                          "4:hex", "-1", "-p", str(port), "127.0.0.1"],
                         capture_output=True, text=True, timeout=20)
    assert out.returncode == 0, out.stderr
    return [int(line.split()[1], 16) for line in out.stdout.splitlines()
            if line.startswith("[")]


async def test_mbpoll_sees_the_test_pattern_and_a_moving_heartbeat(served) -> None:
    bank, server, _, _ = served
    beat = asyncio.create_task(run_heartbeat(bank, lambda: True, period_s=0.2))
    try:
        first = await asyncio.to_thread(mbpoll, server.port)
        await asyncio.sleep(0.5)
        second = await asyncio.to_thread(mbpoll, server.port)
    finally:
        beat.cancel()
    assert first[:2] == [0x1234, 0x5678] and first[2] == MAP_VERSION
    assert second[3] > first[3]                              # heartbeat counts


async def test_heartbeat_stands_still_when_unhealthy() -> None:
    bank = RegisterBank()
    beat = asyncio.create_task(run_heartbeat(bank, lambda: False, period_s=0.05))
    await asyncio.sleep(0.3)
    beat.cancel()
    assert bank.get("heartbeat") == 0


@pytest.mark.parametrize("call", [
    ("diag_query_data", {"msg": b"\x12\x34"}),           # FC8 echo
    ("diag_restart_communication", {"toggle": False}),   # FC8 restart
    ("report_device_id", {}),                            # FC17: named "Pymodbus"
    ("write_file_record", {"records": [FileRecord(file_number=1, record_number=0,
                                                  record_data=b"\x00\x01")]}),  # FC21
    ("read_file_record", {"records": [FileRecord(file_number=1, record_number=0,
                                                 record_length=4)]}),  # FC20
    ("read_device_information", {}),                    # FC43
])
async def test_only_the_register_map_is_served(served, call) -> None:
    """Diagnostics, file records and identification, which pymodbus answers by itself for
    anyone, get "illegal function" and change nothing."""
    bank, server, client, writes = served
    name, kw = call
    before, exceptions = bank.words(0, SIZE), server.exceptions
    rr = await getattr(client, name)(device_id=1, **kw)
    assert rr.isError() and rr.exception_code == 1, rr
    assert b"Pymodbus" not in bytes(getattr(rr, "identifier", b"") or b"")
    assert bank.words(0, SIZE) == before and writes == []
    assert server.exceptions == exceptions + 1
    assert not (await client.read_holding_registers(0, count=2, device_id=1)).isError()
