"""A record per part from its features' measurements, against hand-computed truth."""

from __future__ import annotations

import math

import pytest

from service.compensation.job import job_from_doc
from service.quality.parts import PartAssembler

JOB = job_from_doc({"part_number": "SH-4711", "name": "stepped shaft", "features": [
    {"number": 1, "name": "journal", "nominal_mm": 30.0, "tol_upper_mm": 0.01,
     "tol_lower_mm": -0.01, "tool": 1},
    {"number": 2, "name": "seat", "nominal_mm": 25.0, "tol_upper_mm": 0.005,
     "tol_lower_mm": -0.005, "tool": 2}]})


def test_the_cnc_counter_ends_a_part_and_names_it() -> None:
    parts = PartAssembler(JOB)
    assert parts.add(1, 30.002, 0.001, 10.0, part_counter=41) is None
    assert parts.add(1, 30.004, 0.002, 10.5, part_counter=41) is None  # a second frame
    assert parts.add(2, 25.007, 0.001, 11.0, part_counter=41) is None
    done = parts.add(1, 30.0, 0.001, 20.0, part_counter=42)
    assert done.serial == "SH-4711-41" and done.time_s == 10.0
    f1, f2 = done.features
    w1, w2 = 1 / 0.001 ** 2, 1 / 0.002 ** 2
    assert f1.diameter_mm == pytest.approx((w1 * 30.002 + w2 * 30.004) / (w1 + w2))
    assert f1.uncertainty_mm == pytest.approx(1 / math.sqrt(w1 + w2)) and f1.n == 2
    assert (f1.verdict, f2.verdict, done.verdict) == ("ok", "above", "out")


def test_without_a_counter_coming_back_to_a_feature_starts_the_next_part() -> None:
    parts = PartAssembler(JOB)
    parts.add(1, 30.0, 0.001, 1.0)
    assert parts.add(1, 30.0, 0.001, 1.1) is None  # frames along the journal: one part
    parts.add(2, 25.0, 0.001, 2.0)
    first = parts.add(1, 30.001, 0.001, 3.0)
    assert first.serial == "SH-4711-g1" and first.verdict == "ok"
    second = parts.finish()  # the job changed: the part under way ends as it is
    assert second.serial == "SH-4711-g2" and second.verdict == "incomplete"
    assert second.features[1].verdict == "missing" and second.features[1].diameter_mm is None
    assert parts.finish() is None


def test_without_a_counter_a_pause_ends_a_part_of_one_feature() -> None:
    one = job_from_doc({"part_number": "PIN", "name": "pin", "features": [
        {"number": 1, "name": "d", "nominal_mm": 8.0, "tol_upper_mm": 0.01,
         "tol_lower_mm": -0.01, "tool": 1}]})
    parts = PartAssembler(one, gap_s=5.0)
    for k in range(20):  # 2 s of frames on one part
        assert parts.add(1, 8.001, 0.001, 100.0 + k * 0.1) is None
    done = parts.add(1, 8.002, 0.001, 110.0)  # the next part, after a pause
    assert done.serial == "PIN-g1" and done.features[0].n == 20


def test_a_feature_the_job_does_not_have_is_refused() -> None:
    with pytest.raises(KeyError, match="feature 5 is not in job"):
        PartAssembler(JOB).add(5, 30.0, 0.001, 1.0)
