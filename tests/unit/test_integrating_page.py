"""The integrator's page speaks to integrators: no module path, no library internals (those
are the developers' page's)."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_the_integrating_page_names_no_module() -> None:
    page = (ROOT / "docs" / "integrating.md").read_text()
    found = [line for line in page.splitlines()
             if re.search(r"service/|drivers/|pymodbus|SimDevice", line)]
    assert not found, found
