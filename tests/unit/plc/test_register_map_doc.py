"""docs/modbus-register-map.md says exactly what the code does."""

from pathlib import Path

from drivers.plc.registers import markdown_tables

DOC = Path(__file__).resolve().parents[3] / "docs" / "modbus-register-map.md"


def test_document_holds_the_tables_the_code_defines() -> None:
    text = DOC.read_text()
    assert markdown_tables() in text, (
        "docs/modbus-register-map.md differs from drivers/plc/registers.py; regenerate the "
        "tables with: .venv/bin/python -m drivers.plc.registers")


def test_every_entry_a_job_may_have_has_its_block() -> None:
    """The job's bounds are those the register map serves (an entry past it had no block,
    an offset number past 16 bits no register)."""
    from drivers.plc.registers import ENTRY_BLOCKS
    from service.compensation.job import MAX_ENTRIES, MAX_ENTRY_NUMBER, MAX_TOOLS

    assert ENTRY_BLOCKS == MAX_ENTRIES >= MAX_TOOLS
    assert MAX_ENTRY_NUMBER <= 0xFFFF


def test_every_feature_a_job_may_have_has_its_result_block_and_the_codes_are_documented(
        ) -> None:
    from drivers.plc.registers import FEATURE_BLOCKS
    from service.compensation.job import MAX_FEATURES
    from service.quality.results import markdown_table

    assert FEATURE_BLOCKS == MAX_FEATURES
    assert markdown_table() in DOC.read_text(), (
        "docs/modbus-register-map.md lacks the reason codes of service/quality/results.py "
        "(markdown_table())")
