"""The Fanuc and Siemens outlines in the register map (the pull handshake, and reading the
results back) name each register as the register table does: its address, and whether a CNC
may write it."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from drivers.plc.registers import REGISTERS

ROOT = Path(__file__).resolve().parents[3]
ROW = re.compile(r"^\| `(\w+)` \| (\d+) \| (reads|writes) \|$")


def example_rows(control: str) -> list[tuple[str, int, str]]:
    page = (ROOT / "docs" / "modbus-register-map.md").read_text()
    section = page.split(f"### {control}")[1].split("\n### ")[0]
    return [(m[1], int(m[2]), m[3]) for m in map(ROW.match, section.splitlines()) if m]


@pytest.mark.parametrize("control", ["Fanuc", "Siemens"])
def test_each_register_an_example_uses_is_the_tables(control: str) -> None:
    table = {r.name: r for r in REGISTERS}
    rows = example_rows(control)
    assert len(rows) >= 17, rows  # the pull handshake's registers, the heartbeat, the status
    for name, address, how in rows:
        assert name in table, name
        assert table[name].address == address, (name, address, table[name].address)
        assert (how == "writes") == table[name].writable, (name, how)
    used = {name for name, _, _ in rows}
    pull = {r.name for r in REGISTERS if r.name.startswith(("request_", "cnc_"))}
    assert pull <= used, pull - used
    # Reading the results back: the request, its answer and the part's verdict.
    results = {"measure_feature", "measure_request", "measured_seq", "measured_verdict",
               "measured_reason", "part_verdict"}
    assert results <= used, results - used
