"""A job's features and tools: documents read back, every refusal naming its field, and
diameters recognised only when exactly one feature fits."""

from __future__ import annotations

import json
import re

import pytest

from service.compensation import CompensationSettings
from service.compensation.job import Job, JobError, JobFeature, JobTool, OffsetEntry, job_from_doc

# The paper's four-segment stepped shaft, finished by two tools (rough sizes).
SHAFT = {
    "part_number": "SH-4711", "name": "stepped shaft",
    "features": [
        {"number": 1, "name": "journal", "nominal_mm": 30.0, "tol_upper_mm": 0.02,
         "tol_lower_mm": -0.02, "tool": 1},
        {"number": 2, "name": "bearing seat", "nominal_mm": 25.0, "tol_upper_mm": 0.008,
         "tol_lower_mm": -0.008, "tool": 1, "empirical_mm": 0.002},
        {"number": 3, "name": "collar", "nominal_mm": 40.0, "tol_upper_mm": 0.05,
         "tol_lower_mm": -0.05, "tool": 2},
        {"number": 4, "name": "slender end", "nominal_mm": 18.0, "tol_upper_mm": 0.02,
         "tol_lower_mm": -0.02, "tool": 2, "empirical_mm": 0.004},
    ],
    "tools": [{"number": 1, "wear_entry": 10001, "gain": 0.4}, {"number": 2}],
}


def test_a_document_reads_back_whole() -> None:
    job = job_from_doc(SHAFT)
    assert job.tool_numbers() == (1, 2)
    assert [f.number for f in job.features_of(2)] == [3, 4]
    assert job.tool(1).wear_entry == 10001 and job.tool(2).gain is None
    assert job_from_doc(json.loads(json.dumps(job.to_doc()))) == job
    assert isinstance(job.feature(3).nominal_mm, float)


def test_settings_for_a_feature_take_its_bands_and_its_tools_law() -> None:
    job = job_from_doc(SHAFT)
    base = CompensationSettings(nominal_mm=99.0, gain=0.3, deadband_mm=0.001)
    s = job.settings_for(job.feature(2), base)
    assert (s.nominal_mm, s.tol_upper_mm, s.tol_lower_mm, s.gain) == (25.0, 0.008, -0.008, 0.4)
    assert s.deadband_mm == 0.001  # the job's default
    assert job.settings_for(job.feature(3), base).gain == 0.3
    # half the narrowest band; tool 1's features go to its wear entry (``wear_entry``)
    assert job.entry_of(job.feature(1)) == OffsetEntry(1, 10001)
    assert job.max_disagreement_mm(OffsetEntry(1, 10001)) == pytest.approx(0.008)
    assert job.entries()[1] == OffsetEntry(2)


@pytest.mark.parametrize(("change", "named"), [
    (lambda d: d["features"][1].update(number=1), "features[1].number: 1 is given to two"),
    (lambda d: d["features"][2].update(nominal_mm=-4.0), "features[2].nominal_mm"),
    (lambda d: d["features"][0].update(tol_upper_mm=-0.01), "features[0].tolerance"),
    (lambda d: d["features"][3].update(tool=0), "features[3].tool: 1 to 9999"),
    (lambda d: d["features"][3].update(empirical_mm=2.0), "features[3].empirical_mm"),
    (lambda d: d["features"][0].update(nominal_mm="30"), "features[0].nominal_mm: '30'"),
    (lambda d: d["features"][0].update(nominal_mm=True), "features[0].nominal_mm: True"),
    (lambda d: d["features"][0].update(spindle=3), "features[0].spindle: not a field"),
    (lambda d: d["features"][0].pop("tool"), "features[0].tool: missing"),
    (lambda d: d["tools"].append({"number": 7}), "tools[2].number: tool 7 finishes no"),
    (lambda d: d["tools"][0].update(gain=1.5), "tools[0].gain"),
    # The controller's own bound (a trend gain of 1 stopped the gauge from starting).
    (lambda d: d["tools"][1].update(trend_gain=1.0), "tools[1].trend_gain: within [0, 1)"),
    # Tool 3 finishes no feature (feature 3 does exist: the check looked at features).
    (lambda d: d["tools"].append({"number": 3}), "tools[2].number: tool 3 finishes no"),
    (lambda d: d.update(part_number="SH\r4711"), "part_number: printable text only, not U+000D"),
    (lambda d: d.update(part_number="\ud800"), "part_number: printable text only, not U+D800"),
    (lambda d: d["features"][0].update(name="a\x00b"), "features[0].name: printable text"),
    (lambda d: d["features"][0].update(name="a\x0fb"), "features[0].name: printable text"),
    (lambda d: d["features"][0].update(name="a\x14b"), "features[0].name: printable text"),
    (lambda d: d.update(name="x" * 81), "name: at most 80 characters, not 81"),
    (lambda d: d.update(part_number=" "), "part_number: must not be empty"),
    (lambda d: d.update(features=[]), "features: 1 to 32"),
])
def test_a_bad_document_is_refused_naming_the_field(change, named: str) -> None:
    doc = json.loads(json.dumps(SHAFT))
    change(doc)
    with pytest.raises(JobError, match=re.escape(named)):
        job_from_doc(doc)


def test_a_diameter_is_the_one_feature_whose_nominal_is_near() -> None:
    job = job_from_doc(SHAFT)
    assert job.recognise(25.012).feature.number == 2
    assert job.recognise(17.7).feature.number == 4
    far = job.recognise(33.0)
    assert far.feature is None and "fits no feature" in far.reason and "30 mm" in far.reason
    assert job.recognise(float("nan")).feature is None
    near = Job("P", "two close", (JobFeature(1, "a", 20.0, 0.01, -0.01, 1),
                                  JobFeature(2, "b", 20.6, 0.01, -0.01, 1)))
    between = near.recognise(20.3)
    assert between.feature is None and "must name the feature" in between.reason


def test_unknown_features_and_tools_are_named() -> None:
    job = job_from_doc(SHAFT)
    with pytest.raises(KeyError, match=r"feature 9 is not in job 'SH-4711'.*1, 2, 3, 4"):
        job.feature(9)
    with pytest.raises(KeyError, match="tool 5 finishes no feature"):
        job.tool(5)


def test_todays_single_feature_is_a_job_of_one() -> None:
    job = Job.single(CompensationSettings(nominal_mm=30.0, tol_upper_mm=0.01,
                                          tol_lower_mm=-0.02))
    assert [(f.number, f.nominal_mm, f.tol_lower_mm, f.tool) for f in job.features] == [
        (1, 30.0, -0.02, 1)]
    assert job.problems() == []
    with pytest.raises(JobError, match="nominal_mm"):
        Job.single(CompensationSettings())
    assert job.tool(1) == JobTool(1)
