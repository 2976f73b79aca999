"""The AQDEF files the gauge writes, read by an independent reader (``aqdefreader``, from
the package index): what a plant's quality system would take from them."""

from __future__ import annotations

import contextlib
import io
from pathlib import Path

from aqdefreader import read_dfq_file


def _number(value: object) -> float | None:
    # The reader turns "30,0012" into a number and leaves "30.0012" as text.
    return None if value is None else float(str(value).replace(",", "."))


def characteristics(path: Path) -> tuple[int, list[dict]]:
    """(K0100, each characteristic of the file's one part): its number, description,
    nominal, lower and upper limits and its values, as ``aqdefreader`` reads them."""
    with contextlib.redirect_stdout(io.StringIO()):  # it prints what it detects
        dfq = read_dfq_file(str(path))
    assert dfq.part_count() == 1, dfq.part_count()
    declared = int(path.read_bytes().split(b"\r\n", 1)[0].split()[1])  # K0100, first
    out = [{"number": str(c.get_data("K2001")), "description": c.get_data("K2002"),
            "nominal": _number(c.get_data("K2101")), "lower": _number(c.get_data("K2110")),
            "upper": _number(c.get_data("K2111")),
            "values": [_number(m.value) for m in c.get_measurements()]}
           for c in dfq.get_part(0).get_characteristics()]
    return declared, out
