"""``serve`` with Modbus/TCP Security: a CNC with a certificate of the plant's authority
sets the feature over TLS; a plain client is refused at the handshake, counted in the status
and the metrics; a missing certificate file stops the start with its name."""

from __future__ import annotations

import time

import pytest
from pymodbus.client import ModbusTcpClient, ModbusTlsClient
from pymodbus.exceptions import ModbusException

from drivers.plc.registers import RegisterType, WordOrder, mm_to_units, to_words
from drivers.plc.tls import client_context
from tests.e2e.conftest import start_service, stop_service, wait_ready
from tests.integration.pki import Authority


def _tls_toml(files) -> str:
    return (f'tls = {{ certfile = "{files.certfile}", keyfile = "{files.keyfile}", '
            f'cafile = "{files.cafile}" }}')


def test_the_cnc_writes_over_tls_and_a_plain_client_is_refused(tmp_path) -> None:
    plant = Authority(tmp_path / "pki", "plant-ca")
    svc = start_service(tmp_path, modbus_toml=_tls_toml(plant.issue("gauge", server=True)))
    try:
        assert wait_ready(svc)
        ctx = client_context(plant.issue("cnc", server=False))
        ctx.check_hostname = False  # pymodbus's synchronous client gives no server name; the
        # chain is still verified against the plant's authority
        cnc = ModbusTlsClient("127.0.0.1", port=svc.modbus_port, timeout=3, retries=0,
                              sslctx=ctx)
        assert cnc.connect()
        words = to_words(mm_to_units(25.0), RegisterType.I32, WordOrder.BIG)
        assert not cnc.write_registers(14, words, device_id=1).isError()
        cnc.close()
        for _ in range(50):
            if svc.get("/api/v1/compensation").json()["settings"]["nominal_mm"] == 25.0:
                break
            time.sleep(0.1)
        assert svc.get("/api/v1/compensation").json()["settings"]["nominal_mm"] == 25.0
        plain = ModbusTcpClient("127.0.0.1", port=svc.modbus_port, timeout=2, retries=0)
        plain.connect()
        with pytest.raises(ModbusException):
            plain.read_holding_registers(2, count=1, device_id=1)
        plain.close()
        modbus = svc.get("/api/v1/status").json()["modbus"]
        assert modbus["tls"] and modbus["refused_handshakes"] >= 1
        assert "does not speak TLS" in modbus["last_refused_handshake"]
        assert "shaftgauge_modbus_refused_handshakes_total 1.0" in svc.get("/metrics").text
    finally:
        stop_service(svc)


def test_a_missing_certificate_file_stops_the_start_naming_it(tmp_path) -> None:
    plant = Authority(tmp_path / "pki", "plant-ca")
    files = plant.issue("gauge", server=True)
    files.cafile.unlink()
    with pytest.raises(RuntimeError) as err:
        start_service(tmp_path, modbus_toml=_tls_toml(files))
    assert f"modbus.tls.cafile {files.cafile}: no such file" in str(err.value)
    assert "Traceback" not in str(err.value)
