"""The defaults the register map's CNC programmer reads are the code's."""

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
