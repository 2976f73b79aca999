"""Who may steer the tool: the service's Modbus server takes writes only from
``modbus.writers``, connections only from ``modbus.allowed_clients``, a feature write whole or
not at all, and garbage on the wire without filling its log. Clients on other loopback
addresses play the other machines on the plant network."""

from __future__ import annotations

import contextlib
import os
import socket
import time
from collections.abc import Iterator

import httpx
import pytest
from pymodbus.client import ModbusTcpClient
from pymodbus.exceptions import ModbusException

from drivers.plc.registers import BY_NAME, RegisterType, WordOrder, mm_to_units, to_words
from tests.e2e.conftest import Service, start_service, stop_service, wait_ready

CNC, READER, STRANGER = "127.0.0.1", "127.0.0.2", "127.0.0.3"
ACCESS = f"""allowed_clients = ["{CNC}", "{READER}"]
writers = ["{CNC}"]
max_connections = 4
"""


@pytest.fixture(scope="module")
def gauge(tmp_path_factory) -> Iterator[Service]:
    tmp = tmp_path_factory.mktemp("access")
    svc = start_service(tmp, modbus_toml=ACCESS)
    try:
        assert wait_ready(svc)
        yield svc
    finally:
        stop_service(svc)


def client(svc: Service, source: str) -> ModbusTcpClient:
    c = ModbusTcpClient("127.0.0.1", port=svc.modbus_port, timeout=2, retries=0,
                        source_address=(source, 0))
    c.connect()
    return c


def feature_words(nominal_mm: float, upper_mm: float, lower_mm: float) -> list[int]:
    return [w for v in (nominal_mm, upper_mm, lower_mm)
            for w in to_words(mm_to_units(v), RegisterType.I32, WordOrder.BIG)]


def feature(svc: Service) -> dict:
    return svc.get("/api/v1/feature").json()


def test_a_reader_reads_and_its_writes_change_nothing(gauge) -> None:
    before = feature(gauge)
    with client(gauge, READER) as c:
        rr = c.read_holding_registers(0, count=30, device_id=1)
        assert not rr.isError() and rr.registers[:2] == [0x1234, 0x5678]
        nominal = c.write_registers(BY_NAME["nominal"].address,
                                    feature_words(30.015, 0.02, -0.02)[:2], device_id=1)
        command = c.write_register(BY_NAME["command"].address, 3, device_id=1)
    assert nominal.isError() and nominal.exception_code == 0x01
    assert command.isError() and command.exception_code == 0x01
    time.sleep(0.5)
    assert feature(gauge) == before
    st = gauge.get("/api/v1/status").json()["modbus"]
    assert st["refused_writes"] >= 2 and READER in st["last_refused"]
    assert f"{READER} may not write" in gauge.stderr()
    counted = [line for line in gauge.get("/metrics").text.splitlines()
               if line.startswith("shaftgauge_modbus_refused_writes_total ")]
    assert counted and float(counted[0].split()[1]) >= 2


def test_a_stranger_cannot_connect(gauge) -> None:
    c = ModbusTcpClient("127.0.0.1", port=gauge.modbus_port, timeout=1, retries=0,
                        source_address=(STRANGER, 0))
    c.connect()
    rr = None
    try:
        rr = c.read_holding_registers(0, count=2, device_id=1)
    except (ModbusException, OSError):  # disconnected: pymodbus raises or answers an error
        pass
    finally:
        c.close()
    assert rr is None or rr.isError()
    assert f"{STRANGER} may not connect" in gauge.stderr()
    assert gauge.get("/api/v1/status").json()["modbus"]["refused_connections"] >= 1


def test_a_feature_write_is_taken_whole_or_not_at_all(gauge) -> None:
    before = feature(gauge)
    with client(gauge, CNC) as c:
        # A tolerance inside the dead band: each register is in range, the feature is not.
        bad = c.write_registers(BY_NAME["nominal"].address,
                                feature_words(25.0, 0.002, -0.002), device_id=1)
        assert bad.isError() and bad.exception_code == 0x03
        time.sleep(0.5)
        assert feature(gauge) == before
        good = c.write_registers(BY_NAME["nominal"].address,
                                 feature_words(30.0, 0.04, -0.03), device_id=1)
        assert not good.isError()
    deadline = time.monotonic() + 5
    while feature(gauge)["tol_lower_mm"] != pytest.approx(-0.03):
        assert time.monotonic() < deadline, feature(gauge)
        time.sleep(0.1)
    assert feature(gauge) == pytest.approx({"nominal_mm": 30.0, "tol_upper_mm": 0.04,
                                            "tol_lower_mm": -0.03})
    assert f"modbus write from {CNC}: nominal" in gauge.stderr()


def test_connections_beyond_the_limit_are_refused(gauge) -> None:
    held = [socket.create_connection(("127.0.0.1", gauge.modbus_port)) for _ in range(8)]
    try:
        time.sleep(0.5)
        assert gauge.get("/api/v1/status").json()["modbus"]["connections"] <= 4
        assert "modbus.max_connections" in gauge.stderr()
    finally:
        for s in held:
            s.close()


def test_thirty_megabytes_of_garbage_leave_the_log_small(gauge) -> None:
    size0 = gauge.log.stat().st_size
    block = os.urandom(1 << 20)
    sent = 0
    for _ in range(30):
        try:
            with socket.create_connection(("127.0.0.1", gauge.modbus_port), timeout=5) as s:
                s.sendall(block)
                sent += len(block)
        except OSError:  # the server closed a connection it could not frame: next one
            continue
    assert sent >= 20 << 20
    time.sleep(1.0)
    grown = gauge.log.stat().st_size - size0
    print(f"\nFIGURES {sent >> 20} MB of random bytes: the log grew {grown} bytes")
    assert grown < 100_000
    assert httpx.get(gauge.url + "/readyz", timeout=5).status_code == 200


def test_an_alarm_acknowledgement_from_the_register_is_refused_unless_allowed(gauge) -> None:
    """Refused as a write (exception 0x03), so that the CNC knows and ``last_command`` does
    not read as if it was carried out."""
    last = BY_NAME["last_command"].address
    with client(gauge, CNC) as c:
        before = c.read_holding_registers(last, count=1, device_id=1).registers
        answer = c.write_register(BY_NAME["command"].address, 3, device_id=1)
        assert answer.isError() and answer.exception_code == 3
        time.sleep(0.5)
        assert c.read_holding_registers(last, count=1, device_id=1).registers == before
    st = httpx.get(gauge.url + "/api/v1/status", timeout=5).json()["modbus"]
    assert "modbus.acknowledge_command" in st["last_refused"]


def test_idle_readers_never_lock_the_cnc_out(gauge) -> None:
    """Twenty idle connections from a client that may only read fill what readers may hold
    (the rest of max_connections is kept for the writers), and the CNC still connects,
    reads and writes (issue 50, finding 1)."""
    refused = gauge.get("/api/v1/status").json()["modbus"]["refused_connections"]
    held = []
    for _ in range(20):
        s = socket.socket()
        s.bind((READER, 0))
        with contextlib.suppress(OSError):
            s.connect(("127.0.0.1", gauge.modbus_port))
        held.append(s)
    try:
        time.sleep(0.5)
        with client(gauge, CNC) as c:
            r = c.read_holding_registers(BY_NAME["nominal"].address, count=2, device_id=1)
            assert not r.isError(), r
            w = c.write_registers(BY_NAME["nominal"].address,
                                  feature_words(30.0, 0.02, -0.02), device_id=1)
            assert not w.isError(), w
        # At most three of the twenty held (a quarter of the four kept for the writers).
        now = gauge.get("/api/v1/status").json()["modbus"]["refused_connections"]
        assert now - refused >= 17, (refused, now)
    finally:
        for s in held:
            s.close()
