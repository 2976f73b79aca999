"""Measurements as a Q-DAS ASCII transfer file (AQDEF, "DFQ"): pure text, no I/O.

The file is K-field lines, ``K<field>[/<characteristic>] <value>``: the part (K1001 number,
K1002 description), the characteristic (K2001 number, K2002 description, K2022 decimal
places, K2101 nominal, K2110/K2111 lower/upper specification limits, K2142 unit) and K0100
(the number of characteristics), then per measurement a value line ``K0001/1`` followed by
its fields: K0004 date and time (``dd.mm.yyyy/HH:MM:SS``, the gauge's local time), K0005
events (0: none), K0006 batch (here: the calibration the value was measured with, ``cal<id>``),
K0008 operator (the gauge: it measures unattended), K0012 gauge (test equipment) and K0014
part ident (the gauge's measurement sequence number). Values and limits in mm with a decimal
point; text fields without line breaks.

A part may have more characteristics than its diameter (the surface's run-out and roundness,
when the spindle's angle is known): characteristic *i* has its own K2xxx/*i* fields, and a
part's value of it its own ``K0001/i`` line with its K00xx/*i* fields; a characteristic a part
has no value of (the run-out not known yet) has no value line for it.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterable
from dataclasses import dataclass, replace


@dataclass(frozen=True)
class AqdefPart:
    """The header of a transfer file: what was measured, against what.

    Parameters
    ----------
    part_number, part_description : str
        K1001, K1002.
    characteristic_number, characteristic_description : str
        K2001, K2002.
    nominal_mm, lower_limit_mm, upper_limit_mm : float or None
        K2101, K2110, K2111 (absolute limits, mm); None: left out.
    gauge_id : str
        K0012 (and K0008) of every value.
    decimals : int
        K2022, and the decimals written (4: 0.1 um).
    """

    part_number: str
    part_description: str
    characteristic_number: str
    characteristic_description: str
    nominal_mm: float | None
    lower_limit_mm: float | None
    upper_limit_mm: float | None
    gauge_id: str
    decimals: int = 4


    more: tuple[AqdefCharacteristic, ...] = ()


@dataclass(frozen=True)
class AqdefCharacteristic:
    """A characteristic after the first (K2001/i ... for i = 2, 3, ...): its number,
    description and limits (mm; None: left out)."""

    number: str
    description: str
    nominal_mm: float | None = None
    lower_limit_mm: float | None = None
    upper_limit_mm: float | None = None


@dataclass(frozen=True)
class AqdefValue:
    """One measured value (mm) of one part at ``time_s`` (Unix seconds), and its values of
    the part's further characteristics (None: not measured)."""

    value_mm: float
    time_s: float
    part_ident: str
    batch: str = ""
    more: tuple[float | None, ...] = ()


def _text(s: str) -> str:
    return " ".join(str(s).split())  # one line, no tabs


def _characteristics(part: AqdefPart) -> list[AqdefCharacteristic]:
    return [AqdefCharacteristic(part.characteristic_number, part.characteristic_description,
                                part.nominal_mm, part.lower_limit_mm, part.upper_limit_mm),
            *part.more]


def aqdef_lines(part: AqdefPart, values: Iterable[AqdefValue]) -> list[str]:
    """The transfer file's lines (without line ends): ``header_lines`` then
    ``value_lines``. A value that is not finite is left out (a transfer file has no "not a
    number")."""
    return header_lines(part) + value_lines(part, values)


def header_lines(part: AqdefPart) -> list[str]:
    """The part's and its characteristics' lines."""
    fmt = f"{{:.{part.decimals}f}}"
    chars = _characteristics(part)
    out = [f"K0100 {len(chars)}", f"K1001 {_text(part.part_number)}",
           f"K1002 {_text(part.part_description)}"]
    for i, c in enumerate(chars, 1):
        out += [f"K2001/{i} {_text(c.number)}", f"K2002/{i} {_text(c.description)}",
                f"K2022/{i} {part.decimals}"]
        for key, v in (("K2101", c.nominal_mm), ("K2110", c.lower_limit_mm),
                       ("K2111", c.upper_limit_mm)):
            if v is not None and math.isfinite(v):
                out.append(f"{key}/{i} {fmt.format(v)}")
        out.append(f"K2142/{i} mm")
    return out


def value_lines(part: AqdefPart, values: Iterable[AqdefValue]) -> list[str]:
    """The values' lines (a file may be written a page of values at a time)."""
    fmt = f"{{:.{part.decimals}f}}"
    chars = _characteristics(part)
    gauge = _text(part.gauge_id)
    out: list[str] = []
    for v in values:
        stamp = time.strftime("%d.%m.%Y/%H:%M:%S", time.localtime(v.time_s))
        for i, x in enumerate((v.value_mm, *v.more[:len(chars) - 1]), 1):
            if x is None or not math.isfinite(x):
                continue
            out += [f"K0001/{i} {fmt.format(x)}", f"K0004/{i} {stamp}", f"K0005/{i} 0"]
            if v.batch:
                out.append(f"K0006/{i} {_text(v.batch)}")
            out += [f"K0008/{i} {gauge}", f"K0012/{i} {gauge}",
                    f"K0014/{i} {_text(v.part_ident)}"]
    return out


def aqdef_text(part: AqdefPart, values: Iterable[AqdefValue]) -> str:
    """The transfer file as text (CR LF line ends, as Q-DAS tools write them)."""
    return as_text(aqdef_lines(part, values))


def as_text(lines: list[str]) -> str:
    """Lines of a transfer file as its text (CR LF after each, as Q-DAS tools write them)."""
    return "".join(line + "\r\n" for line in lines)


RUNOUT = AqdefCharacteristic("2", "run-out TIR", nominal_mm=0.0)
ROUNDNESS = AqdefCharacteristic("3", "roundness RONt", nominal_mm=0.0)


def from_archive(rows: list[dict], gauge_id: str, part_number: str = "shaft",
                 characteristic: str = "diameter", max_tir_mm: float | None = None) -> str:
    """A transfer file of archived measurements (``CompensationLog.measurements`` rows).

    Each good row is one value: its fused diameter where it has one (what compensation
    judges), else its own. The nominal and limits are those in force at the latest row that
    had a nominal (rows without one have no limits). Where any row knew the surface's
    run-out (``tir_mm``) or roundness (``ront_mm``), those are characteristics 2 and 3, the
    run-out with ``max_tir_mm`` as its upper limit.
    """
    good = [r for r in rows if _good(r)]
    judged = [r for r in rows if r.get("nominal_mm") is not None]
    summary = {"judged": judged[-1] if judged else None,
               "tir": any(r.get("tir_mm") is not None for r in good),
               "ront": any(r.get("ront_mm") is not None for r in good)}
    part = archive_part(summary, gauge_id, part_number, characteristic, max_tir_mm)
    return aqdef_text(part, archive_values(part, good))


def _good(r: dict) -> bool:
    return r["status"] == "ok" and (r["fused_diameter_mm"] is not None
                                    or r["diameter_mm"] is not None)


def archive_part(summary: dict, gauge_id: str, part_number: str = "shaft",
                 characteristic: str = "diameter", max_tir_mm: float | None = None
                 ) -> AqdefPart:
    """The header of an archive's file from what its rows hold (``judged``: the latest row
    with a nominal, or None; ``tir``, ``ront``: whether any good row knew them;
    ``CompensationLog.measurement_summary``)."""
    last = summary["judged"]
    nominal = None if last is None else last["nominal_mm"]
    more = [c for c, key in ((replace(RUNOUT, upper_limit_mm=max_tir_mm), "tir"),
                             (ROUNDNESS, "ront")) if summary[key]]
    return AqdefPart(
        part_number=part_number, part_description=f"{part_number} measured by {gauge_id}",
        characteristic_number="1", characteristic_description=characteristic,
        nominal_mm=nominal,
        lower_limit_mm=None if last is None else nominal + last["tol_lower_mm"],
        upper_limit_mm=None if last is None else nominal + last["tol_upper_mm"],
        gauge_id=gauge_id, more=tuple(replace(c, number=str(i))
                                      for i, c in enumerate(more, 2)))


def archive_values(part: AqdefPart, rows: Iterable[dict]) -> list[AqdefValue]:
    """The values of archived rows (the good ones) for a file with ``part``'s header."""
    keys = ["tir_mm" if c.description == RUNOUT.description else "ront_mm" for c in part.more]
    return [AqdefValue(
        r["fused_diameter_mm"] if r["fused_diameter_mm"] is not None else r["diameter_mm"],
        r["wall_time"], str(r["seq"]),
        "" if r.get("calibration_id") is None else f"cal{r['calibration_id']}",
        tuple(r.get(k) for k in keys))
        for r in rows if _good(r)]


def from_parts(parts: list[dict], job: dict, gauge_id: str) -> str:
    """A transfer file of part records (``JobStore.parts`` rows, oldest first) of one job
    (its stored document): characteristic *i* is the job's *i*-th feature (K2001 its
    number, K2002 its name, its nominal and limits), K1001 the part number, and each part's
    values carry its serial as K0014. A feature a part has no value of has no value line."""
    features = job["features"]

    def char(f: dict) -> AqdefCharacteristic:
        return AqdefCharacteristic(str(f["number"]), f["name"], f["nominal_mm"],
                                   f["nominal_mm"] + f["tol_lower_mm"],
                                   f["nominal_mm"] + f["tol_upper_mm"])

    first, *more = [char(f) for f in features]
    header = AqdefPart(job["part_number"], job.get("name", ""), first.number,
                       first.description, first.nominal_mm, first.lower_limit_mm,
                       first.upper_limit_mm, gauge_id, more=tuple(more))
    values = []
    for p in parts:
        by_number = {r["feature"]: r["diameter_mm"] for r in p["features"]}
        got = [by_number.get(f["number"]) for f in features]
        values.append(AqdefValue(math.nan if got[0] is None else got[0], p["time"],
                                 p["serial"], more=tuple(got[1:])))
    return aqdef_text(header, values)
