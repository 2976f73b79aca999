"""Measurements as a Q-DAS ASCII transfer file (AQDEF, "DFQ"): pure text, no I/O.

The file is K-field lines, ``K<field>[/<index>] <value>``, as Q-DAS' example files write
them: K0100 (the number of characteristics), the part (K1001/1 number, K1002/1 description),
each characteristic (K2001 number, K2002 description, K2022 decimal places, K2101 nominal,
K2110/K2111 lower/upper specification limits, K2142 unit), the catalogues the values refer
to by number (K4090/K4092: operator 1, the gauge itself, which measures unattended;
K4070/K4072: gauge 1, its id), then per measurement a value line ``K0001/i`` followed by its
fields: K0004 date and time (``dd.mm.yyyy/HH:MM:SS``, the gauge's local time), K0005 events
(0: none), K0006 batch (here: the calibration the value was measured with, ``cal<id>``),
K0008 operator and K0012 gauge (their catalogue numbers) and K0014 part ident (the gauge's
measurement sequence number, or a part's serial). Values and limits in mm with a decimal
point; text fields on one line and cut to their fields' lengths (``LENGTHS``); the file is
written in cp1252 (``encoded``), as Q-DAS files are.

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

LENGTHS = {"K1001": 30, "K1002": 80, "K2001": 20, "K2002": 80, "K0006": 14, "K0014": 40,
           "K4092": 40, "K4072": 40}
"""The text fields' lengths (characters), as the AQDEF field list gives them."""
OPERATOR, GAUGE = 1, 1
"""The value lines' operator (K0008) and gauge (K0012): numbers in the file's catalogues."""


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
    feature: int | None = None
    """The job's feature the first characteristic is (None: none, or not known)."""


@dataclass(frozen=True)
class AqdefCharacteristic:
    """A characteristic after the first (K2001/i ... for i = 2, 3, ...): its number,
    description and limits (mm; None: left out)."""

    number: str
    description: str
    nominal_mm: float | None = None
    lower_limit_mm: float | None = None
    upper_limit_mm: float | None = None
    feature: int | None = None
    """The job's feature it is (None: none, or not known)."""
    kind: str = "diameter"
    """What the archive's rows give it: ``diameter``, ``tir`` (run-out) or ``ront``."""


@dataclass(frozen=True)
class AqdefValue:
    """One measured value (mm) of one part at ``time_s`` (Unix seconds), and its values of
    the part's further characteristics (None: not measured)."""

    value_mm: float
    time_s: float
    part_ident: str
    batch: str = ""
    more: tuple[float | None, ...] = ()


def _text(s: str, field: str = "") -> str:
    """One line, no tabs, cut to ``field``'s length."""
    one = " ".join(str(s).split())
    return one[:LENGTHS[field]].rstrip() if field in LENGTHS else one


def encoded(text: str) -> bytes:
    """A transfer file's text as its bytes: cp1252, a character it cannot hold written as
    its name (``\\N{...}``), not lost to a ``?``."""
    return text.encode("cp1252", "namereplace")


def _characteristics(part: AqdefPart) -> list[AqdefCharacteristic]:
    return [AqdefCharacteristic(part.characteristic_number, part.characteristic_description,
                                part.nominal_mm, part.lower_limit_mm, part.upper_limit_mm,
                                part.feature),
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
    out = [f"K0100 {len(chars)}", f"K1001/1 {_text(part.part_number, 'K1001')}",
           f"K1002/1 {_text(part.part_description, 'K1002')}"]
    for i, c in enumerate(chars, 1):
        out += [f"K2001/{i} {_text(c.number, 'K2001')}",
                f"K2002/{i} {_text(c.description, 'K2002')}", f"K2022/{i} {part.decimals}"]
        for key, v in (("K2101", c.nominal_mm), ("K2110", c.lower_limit_mm),
                       ("K2111", c.upper_limit_mm)):
            if v is not None and math.isfinite(v):
                out.append(f"{key}/{i} {fmt.format(v)}")
        out.append(f"K2142/{i} mm")
    out += [f"K4090/{OPERATOR} {OPERATOR}",
            f"K4092/{OPERATOR} {_text('the gauge (unattended)', 'K4092')}",
            f"K4070/{GAUGE} {GAUGE}", f"K4072/{GAUGE} {_text(part.gauge_id, 'K4072')}"]
    return out


def value_lines(part: AqdefPart, values: Iterable[AqdefValue]) -> list[str]:
    """The values' lines (a file may be written a page of values at a time)."""
    fmt = f"{{:.{part.decimals}f}}"
    chars = _characteristics(part)
    out: list[str] = []
    for v in values:
        stamp = time.strftime("%d.%m.%Y/%H:%M:%S", time.localtime(v.time_s))
        for i, x in enumerate((v.value_mm, *v.more[:len(chars) - 1]), 1):
            if x is None or not math.isfinite(x):
                continue
            out += [f"K0001/{i} {fmt.format(x)}", f"K0004/{i} {stamp}", f"K0005/{i} 0"]
            if v.batch:
                out.append(f"K0006/{i} {_text(v.batch, 'K0006')}")
            out += [f"K0008/{i} {OPERATOR}", f"K0012/{i} {GAUGE}",
                    f"K0014/{i} {_text(v.part_ident, 'K0014')}"]
    return out


def aqdef_text(part: AqdefPart, values: Iterable[AqdefValue]) -> str:
    """The transfer file as text (CR LF line ends, as Q-DAS tools write them)."""
    return as_text(aqdef_lines(part, values))


def as_text(lines: list[str]) -> str:
    """Lines of a transfer file as its text (CR LF after each, as Q-DAS tools write them)."""
    return "".join(line + "\r\n" for line in lines)


RUNOUT = AqdefCharacteristic("2", "run-out TIR", nominal_mm=0.0, kind="tir")
ROUNDNESS = AqdefCharacteristic("3", "roundness RONt", nominal_mm=0.0, kind="ront")


def from_archive(rows: list[dict], gauge_id: str, part_number: str = "shaft",
                 characteristic: str = "diameter", max_tir_mm: float | None = None) -> str:
    """A transfer file of archived measurements (``CompensationLog.measurements`` rows).

    Each good row is one value: its fused diameter where it has one (what compensation
    judges), else its own, a value of its feature's characteristic: one characteristic for
    each feature the good rows were measured as (and one for rows of no feature), each with
    the nominal and limits in force at its latest row that had a nominal (rows without one
    have no limits). Where any row knew the surface's run-out (``tir_mm``) or roundness
    (``ront_mm``), those are the last characteristics, the run-out with ``max_tir_mm`` as
    its upper limit.
    """
    good = [r for r in rows if _good(r)]
    judged: dict[int | None, dict] = {}
    for r in rows:
        if r.get("nominal_mm") is not None:
            judged[r.get("feature")] = {k: r[k] for k in ("nominal_mm", "tol_lower_mm",
                                                          "tol_upper_mm")}
    seen = {r.get("feature") for r in good}
    summary = {"features": [{"feature": f, "judged": judged.get(f)} for f in
                            sorted(seen, key=lambda f: -1 if f is None else f)],
               "tir": any(r.get("tir_mm") is not None for r in good),
               "ront": any(r.get("ront_mm") is not None for r in good)}
    part = archive_part(summary, gauge_id, part_number, characteristic, max_tir_mm)
    return aqdef_text(part, archive_values(part, good))


def _good(r: dict) -> bool:
    return r["status"] == "ok" and (r["fused_diameter_mm"] is not None
                                    or r["diameter_mm"] is not None)


def _diameter(group: dict, characteristic: str, alone: bool) -> AqdefCharacteristic:
    """The characteristic of one feature's rows (``feature`` None: rows of no feature;
    ``alone``: the only one, named as it always was)."""
    last, feature = group["judged"], group["feature"]
    nominal = None if last is None else last["nominal_mm"]
    return AqdefCharacteristic(
        "", characteristic if alone or feature is None else f"{characteristic} feature {feature}",
        nominal, None if last is None else nominal + last["tol_lower_mm"],
        None if last is None else nominal + last["tol_upper_mm"], feature)


def archive_part(summary: dict, gauge_id: str, part_number: str = "shaft",
                 characteristic: str = "diameter", max_tir_mm: float | None = None
                 ) -> AqdefPart:
    """The header of an archive's file from what its rows hold (``features``: each feature
    the good rows were measured as, None for none, with its latest row's nominal and
    tolerance in ``judged`` or None; ``tir``, ``ront``: whether any good row knew them;
    ``CompensationLog.measurement_summary``): characteristic *i* numbered *i*."""
    groups = summary["features"] or [{"feature": None, "judged": None}]
    chars = [_diameter(g, characteristic, len(groups) == 1) for g in groups] + [
        c for c, key in ((replace(RUNOUT, upper_limit_mm=max_tir_mm), "tir"),
                         (ROUNDNESS, "ront")) if summary[key]]
    first, *more = [replace(c, number=str(i)) for i, c in enumerate(chars, 1)]
    return AqdefPart(
        part_number=part_number, part_description=f"{part_number} measured by {gauge_id}",
        characteristic_number=first.number, characteristic_description=first.description,
        nominal_mm=first.nominal_mm, lower_limit_mm=first.lower_limit_mm,
        upper_limit_mm=first.upper_limit_mm, gauge_id=gauge_id, more=tuple(more),
        feature=first.feature)


def archive_values(part: AqdefPart, rows: Iterable[dict]) -> list[AqdefValue]:
    """The values of archived rows (the good ones) for a file with ``part``'s header: each
    a value of its feature's characteristic (a row of a feature the header has none of,
    archived after its summary, is left out), and of the run-out and roundness."""
    chars = _characteristics(part)
    slot = {c.feature: i for i, c in enumerate(chars) if c.kind == "diameter"}
    extra = [(i, c.kind + "_mm") for i, c in enumerate(chars) if c.kind != "diameter"]
    out = []
    for r in rows:
        at = slot.get(r.get("feature"))
        if not _good(r) or at is None:
            continue
        got: list[float | None] = [None] * len(chars)
        got[at] = r["fused_diameter_mm"] if r["fused_diameter_mm"] is not None \
            else r["diameter_mm"]
        for i, key in extra:
            got[i] = r.get(key)
        out.append(AqdefValue(math.nan if got[0] is None else got[0], r["wall_time"],
                              str(r["seq"]), "" if r.get("calibration_id") is None
                              else f"cal{r['calibration_id']}", tuple(got[1:])))
    return out


def from_parts(parts: list[dict], job: dict, gauge_id: str) -> str:
    """A transfer file of part records (``JobStore.parts`` rows, oldest first) of one job
    (its stored document): characteristic *i* is the job's *i*-th feature (K2001 its
    number, K2002 its name, its nominal and limits), K1001 the part number, and each part's
    values carry its serial as K0014. A feature a part has no value of has no value line."""
    features = job["features"]

    def char(f: dict) -> AqdefCharacteristic:
        return AqdefCharacteristic(str(f["number"]), f["name"], f["nominal_mm"],
                                   f["nominal_mm"] + f["tol_lower_mm"],
                                   f["nominal_mm"] + f["tol_upper_mm"], f["number"])

    first, *more = [char(f) for f in features]
    header = AqdefPart(job["part_number"], job.get("name", ""), first.number,
                       first.description, first.nominal_mm, first.lower_limit_mm,
                       first.upper_limit_mm, gauge_id, more=tuple(more),
                       feature=first.feature)
    values = []
    for p in parts:
        by_number = {r["feature"]: r["diameter_mm"] for r in p["features"]}
        got = [by_number.get(f["number"]) for f in features]
        values.append(AqdefValue(math.nan if got[0] is None else got[0], p["time"],
                                 p["serial"], more=tuple(got[1:])))
    return aqdef_text(header, values)
