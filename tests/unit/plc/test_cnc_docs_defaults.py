"""The defaults the register map's CNC programmer reads (the timing, the results' handshake)
are the code's."""

from __future__ import annotations

from pathlib import Path

import pytest

from service.config import MeasurementSettings, PlcSettings

ROOT = Path(__file__).resolve().parents[3]


@pytest.mark.parametrize(("name", "default"), [
    ("measurement.max_age_s", MeasurementSettings().max_age_s),
    ("plc.ack_timeout_s", PlcSettings().ack_timeout_s),
])
def test_the_register_map_gives_the_codes_defaults(name: str, default: float) -> None:
    page = (ROOT / "docs" / "modbus-register-map.md").read_text()
    assert f"`{name}` ({default:g} s by default)" in page, (name, default)


def test_the_results_section_gives_the_codes_defaults() -> None:
    from service.config import ModbusSettings

    page = (ROOT / "docs" / "modbus-register-map.md").read_text()
    m = ModbusSettings()
    assert f"`modbus.result_measurements` ({m.result_measurements})" in page
    assert f"`modbus.result_within_s` ({m.result_within_s:g} s)" in page
