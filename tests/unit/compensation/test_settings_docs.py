"""The manual's table of the compensation settings is the code's: every setting, its range,
default and unit (``service.compensation.settings.markdown_table``)."""

from __future__ import annotations

from dataclasses import fields
from pathlib import Path

from service.compensation.settings import CompensationSettings, attribute_docs, markdown_table

ROOT = Path(__file__).resolve().parents[3]


def test_the_manual_gives_each_setting_with_the_codes_default() -> None:
    page = (ROOT / "docs" / "integrating.md").read_text()
    assert markdown_table() in page, ("docs/integrating.md's settings table differs from the "
                                      "code's: paste service.compensation.settings."
                                      "markdown_table()")


def test_every_setting_is_described() -> None:
    described = attribute_docs()
    missing = [f.name for f in fields(CompensationSettings) if not described.get(f.name)]
    assert not missing, f"settings without a line in the Attributes: {missing}"


def test_the_table_says_the_default_in_force() -> None:
    table = markdown_table()
    assert "| `gain` | float | (0, 1] | 0.3 |" in table
    assert "| `shadow` | bool | true or false | true |" in table
    assert '| `law` | text | "window", "predictive" | "predictive" |' in table
