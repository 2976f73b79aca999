"""SPC and type-1 gauge studies through the API, on a gauge built on the simulated rig."""

from __future__ import annotations

import time

import pytest
from fastapi.testclient import TestClient

from drivers.plc.registers import FaultBit, StatusBit
from service.api.app import create_app
from service.runtime.status_words import status_words
from service.serve import Children, build
from tests.unit.service.conftest import TECHNICIAN, make_settings

FAST = {"measurement": {"fuse_frames": 3},
        "spc": {"subgroup_size": 4, "member_spacing": 1, "every_s": 0.0,
                "baseline_subgroups": 3}}


@pytest.fixture
def quality(tmp_path):
    gauge, _ = build(make_settings(tmp_path, **FAST), Children())
    with TestClient(create_app(gauge)) as c:
        c.gauge = gauge
        yield c


def wait_for(predicate, timeout_s: float = 30.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.1)
    return False


def test_spc_figures_fill_and_reset(quality) -> None:
    c = quality
    assert wait_for(lambda: c.get("/api/v1/spc").json()["baseline"]["complete"])
    f = c.get("/api/v1/spc").json()
    assert f["n"] >= 12 and f["cpk"] is not None and f["cp"] is not None
    assert f["limits"]["lcl_mm"] < f["limits"]["center_mm"] < f["limits"]["ucl_mm"]
    assert abs(f["mean_mm"] - 30.0) < 0.01 and len(f["cpk_ci"]) == 2
    assert {"pp", "ppk", "std_mm", "violations", "points"} <= set(f)
    assert c.post("/api/v1/spc/reset").status_code == 401
    r = c.post("/api/v1/spc/reset", headers={"X-API-Key": TECHNICIAN})
    assert r.status_code == 200 and not r.json()["baseline"]["complete"]


def test_a_gauge_study_holds_offsets_and_reports_cg_cgk(quality) -> None:
    c, key = quality, {"X-API-Key": TECHNICIAN}
    assert c.post("/api/v1/gauge-studies", json={"certified_mm": 30.0}).status_code == 401
    for bad in ({"certified_mm": 30.0, "n": 10}, {"certified_mm": "30"}, {"n": 25},
                {"certified_mm": 30.0, "tolerance_mm": 0}):
        assert c.post("/api/v1/gauge-studies", json=bad, headers=key).status_code == 422, bad
    # 3 frames a value here (fast): about 1 um of spread, capable for a 0.1 mm tolerance
    r = c.post("/api/v1/gauge-studies", json={"certified_mm": 30.0, "n": 25,
                                              "tolerance_mm": 0.1}, headers=key)
    assert r.status_code == 202, r.text
    sid = r.json()["id"]
    again = c.post("/api/v1/gauge-studies", json={"certified_mm": 30.0, "n": 25},
                   headers=key)
    assert again.status_code == 409 and f"study {sid} is running" in again.json()["detail"]
    held = c.get("/api/v1/status").json()["compensation"]["held"]
    assert held and "gauge study" in held
    assert wait_for(lambda: c.get("/api/v1/gauge-studies").json()["running"] is None, 60)
    listed = c.get("/api/v1/gauge-studies").json()
    study = listed["items"][0]
    assert study["id"] == sid and study["state"] == "done" and len(study["values"]) == 25
    res = study["result"]
    assert res["n"] == 25 and res["cg"] > 1.33 and res["cgk"] > 1.33 and res["capable"]
    assert abs(res["bias"]) < 0.002
    assert listed["blocking"] is None
    assert c.get("/api/v1/status").json()["compensation"]["held"] is None


def test_a_failed_study_blocks_offset_writes_and_says_why(quality) -> None:
    c, key = quality, {"X-API-Key": TECHNICIAN}
    # a master certified 10 um off what the gauge sees: bias > 0.1 T -> Cgk < 0
    r = c.post("/api/v1/gauge-studies", json={"certified_mm": 30.010, "n": 25}, headers=key)
    assert r.status_code == 202
    assert r.json()["tolerance_mm"] == pytest.approx(0.04)  # the feature's: +-0.02
    assert wait_for(lambda: c.get("/api/v1/gauge-studies").json()["latest"] is not None, 60)
    st = c.get("/api/v1/gauge-studies").json()
    assert st["latest"]["result"]["capable"] is False
    assert "Cgk" in st["blocking"]
    problems = {p["code"]: p["text"] for p in c.get("/api/v1/status").json()["problems"]}
    assert "gauge_study" in problems and "only proposed" in problems["gauge_study"]
    g = c.gauge
    assert wait_for(lambda: all(ch.controller.writes_blocked
                               for _, ch in g.compensation.in_force()), 5)
    _, faults, _ = status_words(g.health.snapshot())
    assert FaultBit.GAUGE_STUDY_FAILED in faults
    assert FaultBit.MASTER_CHECK_DUE not in faults


def test_the_rule_violation_bit_follows_the_spc(quality) -> None:
    g = quality.gauge
    snap = g.health.snapshot()
    status, _, _ = status_words(snap)
    assert (StatusBit.RULE_VIOLATION in status) == g.spc.rule_violation


def test_a_study_names_its_feature_and_keeps_only_its_masters_values(quality) -> None:
    """The second outside probe: on a job of four features a study named none and took all
    four features' values (26 to 34 mm) as the 30 mm master's, and ended capable of nothing
    true. A job of several features needs the feature; values far from the master are
    refused and counted, never kept."""
    c, key = quality, {"X-API-Key": TECHNICIAN}
    job = {"part_number": "TWO", "name": "two", "features": [
        {"number": 1, "name": "journal", "nominal_mm": 30.0, "tol_upper_mm": 0.05,
         "tol_lower_mm": -0.05, "tool": 1},
        {"number": 2, "name": "collar", "nominal_mm": 34.0, "tol_upper_mm": 0.05,
         "tol_lower_mm": -0.05, "tool": 1}]}
    assert c.post("/api/v1/jobs", headers=key,
                  json={"document": job, "activate": True}).status_code == 201
    r = c.post("/api/v1/gauge-studies", json={"certified_mm": 30.0, "n": 25}, headers=key)
    assert r.status_code == 422 and "name the one" in r.json()["detail"], r.text
    c.gauge.camera.diameter_mm = 34.0  # the collar under the laser, not the master
    r = c.post("/api/v1/gauge-studies", json={"certified_mm": 30.0, "n": 25, "feature": 1},
               headers=key)
    assert r.status_code == 202, r.text
    assert wait_for(lambda: (c.get("/api/v1/gauge-studies").json()["running"] or {})
                    .get("refused", 0) >= 2)
    c.gauge.camera.diameter_mm = 30.0  # the master clamped
    assert wait_for(lambda: c.get("/api/v1/gauge-studies").json()["running"] is None, 120)
    study = c.get("/api/v1/gauge-studies").json()["items"][0]
    assert study["state"] == "done" and len(study["values"]) == 25
    assert all(abs(v - 30.0) < 0.05 for v in study["values"]), study["values"]
    assert "values refused as not the master's" in study["reason"], study
