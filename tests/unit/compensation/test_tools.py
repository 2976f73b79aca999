"""Per-tool compensation of a four-feature part finished by two tools that wear at their
own rates, one feature deflecting: a small lathe of the test's own (wear, deflection and
scatter per feature), against the tolerances."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from service.compensation import CompensationSettings, Kind, MeasurementIn
from service.compensation.entries import JobCompensation
from service.compensation.job import JobError, OffsetEntry, job_from_doc

WEAR_UM_PER_PART = {1: 1.2, 2: 2.5}
DEFLECTION_UM = {4: 8.0}  # the slender end cuts larger
JOB = {"part_number": "SH-4711", "name": "stepped shaft", "features": [
    {"number": 1, "name": "journal", "nominal_mm": 30.0, "tol_upper_mm": 0.015,
     "tol_lower_mm": -0.015, "tool": 1},
    {"number": 2, "name": "bearing seat", "nominal_mm": 25.0, "tol_upper_mm": 0.012,
     "tol_lower_mm": -0.012, "tool": 1},
    {"number": 3, "name": "collar", "nominal_mm": 40.0, "tol_upper_mm": 0.02,
     "tol_lower_mm": -0.02, "tool": 2},
    {"number": 4, "name": "slender end", "nominal_mm": 18.0, "tol_upper_mm": 0.015,
     "tol_lower_mm": -0.015, "tool": 2, "empirical_mm": 0.008}]}
BASE = CompensationSettings(shadow=False, dead_time_measurements=0, dead_time_s=0.0,
                            max_age_s=3600.0, max_total_mm=0.5)


def run(job_doc: dict, parts: int, base: CompensationSettings = BASE, seed: int = 1,
        taper_um_per_part: float = 0.0
        ) -> tuple[dict[int, list[float]], dict[OffsetEntry, float],
                   dict[OffsetEntry, list[float]], list]:
    """Deviations (um) per feature of the parts cut, each offset entry's total, the offsets
    written per entry, and every decision as (tool, feature, decision). The slender end
    (feature 4) deflects ``taper_um_per_part`` more with each part (a taper growing as the
    insert wears)."""
    job = job_from_doc(job_doc)
    comp = JobCompensation(job, base)
    totals = dict.fromkeys(comp.entries, 0.0)
    written: dict[OffsetEntry, list[float]] = {e: [] for e in totals}
    for c in comp.entries.values():
        c.controller.observe_cnc_total(0.0, 0.0)
    rng = np.random.default_rng(seed)
    out: dict[int, list[float]] = {f.number: [] for f in job.features}
    decisions, seq, now = [], 0, 0.0
    for k in range(parts):
        for f in job.features:
            entry = job.entry_of(f)
            dev_um = (WEAR_UM_PER_PART[f.tool] * k + DEFLECTION_UM.get(f.number, 0.0)
                      + (taper_um_per_part * k if f.number == 4 else 0.0)
                      + totals[entry] * 1000 + rng.normal(0.0, 1.0))
            out[f.number].append(dev_um)
            seq, now = seq + 1, now + 1.0
            got, d = comp.on_measurement(MeasurementIn(
                seq, now, "ok", f.nominal_mm + dev_um / 1000, 0.0008), now, f.number)
            assert got == entry
            decisions.append((entry.tool, f.number, d))
            if d.kind is Kind.WRITE:
                ctrl = comp.entries[entry].controller
                assert ctrl.check_before_write(d.offset_seq, totals[entry], now) is None
                totals[entry] += d.offset_mm
                written[entry].append(d.offset_mm)
                ctrl.on_write_outcome(d.offset_seq, True, now)
                ctrl.observe_cnc_total(totals[entry], now)
    return out, totals, written, decisions


def test_every_feature_stays_in_tolerance_and_each_tool_gets_its_own_offsets() -> None:
    job = job_from_doc(JOB)
    out, totals, written, decisions = run(JOB, parts=60)
    for f in job.features:
        tol = max(f.tol_upper_mm, -f.tol_lower_mm) * 1000
        worst = max(abs(v) for v in out[f.number])
        assert worst < tol, (f.number, worst, tol)
    for tool in (1, 2):
        own = OffsetEntry(tool)
        assert written[own] and totals[own] == pytest.approx(sum(written[own]))
        # A tool's total carries its own wear, not the other's: 60 parts of wear.
        assert totals[own] * 1000 == pytest.approx(-WEAR_UM_PER_PART[tool] * 60, abs=10.0)
    writes = [(tool, feature) for tool, feature, d in decisions if d.kind is Kind.WRITE]
    assert all(job.feature(feature).tool == tool for tool, feature in writes)


def test_in_shadow_mode_the_features_leave_the_tolerance() -> None:
    out, totals, written, _ = run(JOB, parts=60, base=replace(BASE, shadow=True))
    assert set(totals.values()) == {0.0} and not any(written.values())
    assert max(out[3]) > 20.0 and max(out[1]) > 15.0  # beyond their tolerances


def test_a_deflection_no_empirical_value_takes_holds_the_tool_and_says_which() -> None:
    """Tool 2 may see its features differ by 4 um: the slender end's 8 um deflection,
    without its empirical value, holds it (a split difference would move both)."""
    doc = {**JOB, "features": [dict(f, empirical_mm=0.0) for f in JOB["features"]],
           "tools": [{"number": 2, "max_disagreement_mm": 0.004}]}
    _, _, written, decisions = run(doc, parts=12)
    held = [(tool, d.reason) for tool, _, d in decisions if d.code == "features_disagree"]
    assert held and {tool for tool, _ in held} == {2}
    assert "features 3 and 4 disagree by +" in held[0][1]
    assert 6.0 < float(held[0][1].split("by ")[1].split(" um")[0]) < 10.0
    assert written[OffsetEntry(1)]  # the other tool is not held
    # Its default bound, half its narrowest tolerance (15 um), takes the 8 um: no hold.
    _, _, _, decisions = run({**doc, "tools": []}, parts=12)
    assert not [d for _, _, d in decisions if d.code == "features_disagree"]


def test_a_feature_or_tool_the_job_does_not_have_is_refused() -> None:
    comp = JobCompensation(job_from_doc(JOB), BASE)
    with pytest.raises(KeyError, match="feature 7 is not in job"):
        comp.on_measurement(MeasurementIn(1, 1.0, "ok", 30.0, 0.001), 1.0, 7)


def taper_run(entry_of_4: int | None, parts: int = 80, seed: int = 3
              ) -> tuple[dict[int, list[float]], dict, list[str]]:
    """Tool 2 finishes the collar and the slender end; the end deflects more as the insert
    wears, its taper growing 0.25 um a part (20 um over 80 parts) besides the wear of
    2.5 um a part and its 8 um deflection (no empirical value). Deviations (um) per
    feature, each entry's total, and the decisions' codes."""
    doc = {**JOB, "features": [
        dict(f, empirical_mm=0.0, **({"entry": entry_of_4} if f["number"] == 4 else {}))
        for f in JOB["features"]]}
    out, totals, _, decisions = run(doc, parts, seed=seed, taper_um_per_part=0.25)
    return out, totals, [d.code for _, _, d in decisions]


def test_a_feature_on_an_offset_entry_of_its_own_is_held_to_its_nominal_as_the_taper_grows(
) -> None:
    out, totals, codes = taper_run(entry_of_4=12)
    for n, tol_um in ((1, 15), (2, 12), (3, 20), (4, 15)):
        assert max(abs(v) for v in out[n][5:]) < tol_um, (n, max(out[n]))
    t2, t2_12 = totals[OffsetEntry(2)], totals[OffsetEntry(2, 12)]
    # Each entry carries its own: the end's entry the wear, its deflection and its taper.
    assert (t2 - t2_12) * 1000 == pytest.approx(DEFLECTION_UM[4] + 0.25 * 80, abs=6.0), totals
    assert "features_disagree" not in codes
    # On the tool's one entry the taper outgrows what its features may disagree by (half
    # of 30 um): the tool is held and the part leaves its tolerance.
    out, _, codes = taper_run(entry_of_4=None)
    assert "features_disagree" in codes
    assert max(abs(v) for v in out[4]) > 15 or max(abs(v) for v in out[3]) > 20


def test_offset_entries_in_the_job_document() -> None:
    doc = {**JOB, "features": [dict(f, entry=12) if f["number"] == 4 else f
                               for f in JOB["features"]]}
    job = job_from_doc(doc)
    assert job.entries() == (OffsetEntry(1), OffsetEntry(2), OffsetEntry(2, 12))
    assert [f.number for f in job.features_on(OffsetEntry(2, 12))] == [4]
    assert str(OffsetEntry(2, 12)) == "T2 offset 12" and str(OffsetEntry(1)) == "T1"
    bad = {**JOB, "features": [dict(f, entry=12) if f["number"] in (1, 4) else f
                               for f in JOB["features"]]}
    with pytest.raises(JobError, match=r"features\[3\].entry: offset 12 is tool 1's too"):
        job_from_doc(bad)
    with pytest.raises(JobError, match=r"features\[0\].entry: 1 to 65535, not 0"):
        job_from_doc({**JOB, "features": [dict(JOB["features"][0], entry=0)]})


def test_an_entrys_convention_is_its_tools_radius_and_sign() -> None:
    """The entry holds what the CNC keeps: a tool whose table is in radius gets half the
    offset for the same deviation, one whose positive offset cuts smaller (a bore's) the
    opposite sign; the rest of the job keeps the settings' (diameter, +1)."""
    doc = {**JOB, "tools": [{"number": 1, "programming": "radius"},
                            {"number": 2, "offset_sign": -1}]}
    job = job_from_doc(doc)
    assert (job.settings_for(job.feature(1), BASE).programming,
            job.settings_for(job.feature(3), BASE).offset_sign) == ("radius", -1)
    assert job.settings_for(job.feature(3), BASE).programming == "diameter"

    def first_offset(d: dict, feature: int) -> float:
        comp = JobCompensation(job_from_doc(d), BASE)
        for c in comp.entries.values():
            c.controller.observe_cnc_total(0.0, 0.0)
        f = comp.job.feature(feature)
        for seq in range(1, 30):  # 10 um large every part
            _, dec = comp.on_measurement(MeasurementIn(seq, float(seq), "ok",
                                                       f.nominal_mm + 0.010, 0.001),
                                         float(seq), feature)
            if dec.kind is Kind.WRITE:
                return dec.offset_mm
        raise AssertionError("no offset")

    plain = first_offset(JOB, 1)
    assert plain < 0
    assert first_offset(doc, 1) == pytest.approx(plain / 2)  # radius: half
    assert first_offset(doc, 3) == pytest.approx(-first_offset(JOB, 3))  # the other sign
    for bad, where in (({"number": 1, "programming": "dia"}, r"tools\[0\]\.programming"),
                       ({"number": 1, "offset_sign": 2}, r"tools\[0\]\.offset_sign")):
        with pytest.raises(JobError, match=where):
            job_from_doc({**JOB, "tools": [bad]})
