"""docs/modbus-register-map.md says exactly what the code does."""

from pathlib import Path

from drivers.plc.registers import markdown_tables

DOC = Path(__file__).resolve().parents[3] / "docs" / "modbus-register-map.md"


def test_document_holds_the_tables_the_code_defines() -> None:
    text = DOC.read_text()
    assert markdown_tables() in text, (
        "docs/modbus-register-map.md differs from drivers/plc/registers.py; regenerate the "
        "tables with: .venv/bin/python -m drivers.plc.registers")


def test_every_tool_a_job_may_have_has_its_block() -> None:
    """The job's bound is the one the register map serves (a tool past it had no block)."""
    from drivers.plc.registers import TOOL_BLOCKS
    from service.compensation.job import MAX_TOOLS

    assert TOOL_BLOCKS == MAX_TOOLS
