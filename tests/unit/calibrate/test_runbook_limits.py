"""The technician's runbook gives the verdict's limits and the master's as the code has them."""

from __future__ import annotations

from pathlib import Path

import pytest

from service.calibrate.report import markdown_table
from service.config import MeasurementSettings, QualitySettings

ROOT = Path(__file__).resolve().parents[3]
PAGE = ROOT / "docs" / "runbooks.md"


def test_the_runbook_holds_the_verdicts_limits() -> None:
    assert markdown_table() in PAGE.read_text(), \
        "docs/runbooks.md differs from service.calibrate.report.markdown_table(): paste it"


@pytest.mark.parametrize(("name", "quoted"), [
    ("measurement.master_limit_mm", f"{MeasurementSettings().master_limit_mm:g} mm"),
    ("measurement.max_correction_offset_mm",
     f"{MeasurementSettings().max_correction_offset_mm:g} mm"),
    ("measurement.max_correction_scale_error",
     f"{MeasurementSettings().max_correction_scale_error:g}"),
    ("quality.min_index", f"{QualitySettings().min_index:g}"),
])
def test_the_runbook_quotes_the_codes_defaults(name: str, quoted: str) -> None:
    assert f"`{name}` ({quoted} by default)" in PAGE.read_text(), (name, quoted)
