"""The REST API on a live (simulated) gauge: reading, writing, access, bad bodies."""

from __future__ import annotations

import json
import re

import pytest

from drivers.sim.rig import RigConfig, rig_calibration
from tests.unit.service.conftest import ADMIN, OPERATOR, TECHNICIAN

H = "X-API-Key"
DOC = rig_calibration(RigConfig(triangulation_deg=40.0)).to_document()

# (method, path, a good body, a bad body, the role it needs)
WRITES = [
    ("put", "/api/v1/feature", {"nominal_mm": 30.0, "tol_upper_mm": 0.02,
                                "tol_lower_mm": -0.02},
     {"nominal_mm": "30.0", "tol_upper_mm": 0.02, "tol_lower_mm": -0.02}, "technician"),
    ("put", "/api/v1/compensation", {"gain": 0.5}, {"gain": True}, "admin"),
    ("put", "/api/v1/compensation/shadow", {"shadow": True}, {"shadow": 1}, "technician"),
    ("post", "/api/v1/compensation/command", {"command": "acknowledge"},
     {"command": "explode"}, "technician"),
    ("put", "/api/v1/temperature", {"part_temp_c": 25.0}, {"part_temp_c": "warm"},
     "technician"),
    ("post", "/api/v1/calibrations", {"document": DOC, "note": "test"},
     {"document": DOC, "note": "x", "surprise": 1}, "technician"),
    ("post", "/api/v1/calibrations/1/activate", None, None, "technician"),
    ("post", "/api/v1/master/measure", {"certified_mm": 30.0, "frames": 3},
     {"certified_mm": "30", "frames": 3}, "technician"),
    ("post", "/api/v1/master/correction", {"masters": [{"certified_mm": 30.0,
                                                        "measured_mm": 29.999}]},
     {"masters": []}, "technician"),
]
LOWER = {"technician": OPERATOR, "admin": TECHNICIAN}
KEY_OF = {"technician": TECHNICIAN, "admin": ADMIN}


@pytest.mark.parametrize(("method", "path", "good", "bad", "role"), WRITES,
                         ids=[f"{w[0]} {w[1]}" for w in WRITES])
def test_every_write_needs_the_right_key_and_a_good_body(client, method, path, good, bad,
                                                         role) -> None:
    call = getattr(client, method)
    kw = {} if good is None else {"json": good}
    assert call(path, **kw).status_code == 401
    assert call(path, headers={H: "not-a-key-at-all-0000"}, **kw).status_code == 401
    r = call(path, headers={H: LOWER[role]}, **kw)
    assert r.status_code == 403 and role in r.json()["detail"]
    if bad is not None:
        r = call(path, headers={H: KEY_OF[role]}, json=bad)
        assert r.status_code == 422, r.text
    r = call(path, headers={H: KEY_OF[role]}, **kw)
    assert r.status_code in (200, 201), r.text


def test_reading_is_open_and_shows_a_live_measurement(client) -> None:
    r = client.get("/api/v1/measurements/latest")
    assert r.status_code == 200
    m = r.json()
    assert m["status"] == "ok" and abs(m["diameter_mm"] - 30.0) < 0.02
    assert m["uncertainty_mm"] > 0 and m["deviation_mm"] is not None
    st = client.get("/api/v1/status").json()
    assert st["camera"]["state"] == "streaming" and st["calibration"]["active"]
    assert st["pipeline"]["measured"] >= 1 and "latency" in st["pipeline"]
    assert client.get("/healthz").json() == {"alive": True}
    assert client.get("/readyz").status_code == 200
    text = client.get("/metrics").text
    values = dict(line.rsplit(" ", 1) for line in text.splitlines() if not line.startswith("#"))
    assert abs(float(values["shaftgauge_diameter_mm"]) - 30.0) < 0.02
    assert "# TYPE shaftgauge_healthy gauge" in text


def test_history_pages_newest_first(client) -> None:
    import time

    time.sleep(0.6)
    first = client.get("/api/v1/measurements", params={"limit": 3}).json()
    seqs = [i["seq"] for i in first["items"]]
    assert len(seqs) == 3 and seqs == sorted(seqs, reverse=True)
    nxt = client.get("/api/v1/measurements",
                     params={"limit": 3, "before_seq": first["next_before_seq"]}).json()
    assert all(i["seq"] < seqs[-1] for i in nxt["items"])
    assert client.get("/api/v1/measurements", params={"since": 2, "until": 1}).status_code \
        == 422
    assert client.get("/api/v1/measurements", params={"limit": 0}).status_code == 422


def test_calibration_import_export_activate_round_trip(client) -> None:
    r = client.post("/api/v1/calibrations", headers={H: TECHNICIAN},
                    json={"document": DOC, "note": "40 degree rig"})
    assert r.status_code == 201
    cid = r.json()["id"]
    assert client.get(f"/api/v1/calibrations/{cid}/export").json() == DOC
    items = client.get("/api/v1/calibrations").json()["items"]
    assert items[0]["id"] == cid and not items[0]["active"]
    r = client.post(f"/api/v1/calibrations/{cid}/activate", headers={H: TECHNICIAN})
    assert r.status_code == 200 and r.json()["active"]
    assert client.get("/api/v1/status").json()["calibration"]["id"] == cid
    audit = client.get("/api/v1/calibrations/audit").json()["items"]
    assert [a["action"] for a in audit[:2]] == ["activate", "import"]
    assert re.fullmatch(r"technician \(key api\.keys#\d, testclient\)", audit[0]["who"])


def test_bad_calibration_document_is_422_naming_the_field(client) -> None:
    doc = json.loads(json.dumps(DOC))
    doc["light_plane"]["normal"] = [1.0, 1.0, 0.0]
    r = client.post("/api/v1/calibrations", headers={H: TECHNICIAN}, json={"document": doc})
    assert r.status_code == 422 and "light_plane.normal" in r.json()["detail"]
    assert client.get("/api/v1/calibrations/999").status_code == 404


@pytest.mark.parametrize(("path", "value", "named"), [
    (("light_plane", "d"), -1e308, "light_plane"),
    (("dist_coeffs", 0), -1e308, "dist_coeffs"),
    (("axis", "point", 2), -1e308, "axis.point"),
    (("image_size",), [1, 1], "image_size")])
def test_an_absurd_calibration_is_refused_and_not_activated(client, path, value,
                                                            named) -> None:
    """Finite but absurd (issue 50, finding 4): each was imported and activated with 201,
    and the gauge then reported ok with it. Refused, naming what, and not activated."""
    active = client.get("/api/v1/status").json()["calibration"]["id"]
    doc = json.loads(json.dumps(DOC))
    node = doc
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value
    r = client.post("/api/v1/calibrations", headers={H: TECHNICIAN},
                    json={"document": doc, "activate": True})
    assert r.status_code == 422 and named in r.json()["detail"], r.text
    assert client.get("/api/v1/status").json()["calibration"]["id"] == active


def test_feature_reaches_the_controller_and_registers(client) -> None:
    r = client.put("/api/v1/feature", headers={H: TECHNICIAN},
                   json={"nominal_mm": 31.5, "tol_upper_mm": 0.03, "tol_lower_mm": -0.01})
    assert r.status_code == 200
    assert client.get("/api/v1/feature").json()["nominal_mm"] == 31.5
    assert client.gauge.modbus.bank.get("nominal") == 315_000
    bad = client.put("/api/v1/feature", headers={H: TECHNICIAN},
                     json={"nominal_mm": 31.5, "tol_upper_mm": 0.03, "tol_lower_mm": 0.01})
    assert bad.status_code == 422


def test_inconsistent_tuning_is_refused_naming_the_setting(client) -> None:
    r = client.put("/api/v1/compensation", headers={H: ADMIN},
                   json={"max_step_mm": 0.5, "max_total_mm": 0.1})
    assert r.status_code == 422 and "max_step_mm" in r.json()["detail"]


@pytest.mark.parametrize(("field", "value"), [
    ("max_total_mm", 1e308), ("safe_area_mm", 9.2e18), ("dead_time_s", 9.2e18),
    ("max_age_s", 9.2e18), ("dead_time_measurements", int("9" * 400)),
    ("plausibility_mm", 1e9)])
def test_absurd_tuning_is_refused_naming_the_setting_and_nothing_changes(client, field,
                                                                         value) -> None:
    """Values no machine needs would switch a limit off (a cumulative limit of 1e308 is
    none): refused with the setting's name, and the settings in force stay."""
    before = client.get("/api/v1/compensation").json()
    assert before["settings"]["max_total_mm"] < 1.0, before
    r = client.put("/api/v1/compensation", headers={H: ADMIN}, json={field: value})
    assert r.status_code == 422 and field in r.text, r.text
    assert client.get("/api/v1/compensation").json()["settings"] == before["settings"]


def test_compensation_log_and_shadow(client) -> None:
    r = client.put("/api/v1/compensation/shadow", headers={H: TECHNICIAN},
                   json={"shadow": False})
    assert r.status_code == 200 and r.json()["settings"]["shadow"] is False
    log = client.get("/api/v1/compensation/log", params={"limit": 5}).json()["items"]
    assert log and log[0]["kind"] in ("settings", "held", "refused", "proposed")


def test_openapi_is_served_with_a_reference_page_of_the_gauges_own(client) -> None:
    spec = client.get("/openapi.json").json()
    assert "/api/v1/measurements/latest" in spec["paths"]
    docs = client.get("/docs")  # no page from a CDN: the gauge's own, under its own policy
    assert docs.status_code == 200 and "api-reference.js" in docs.text
    assert "cdn" not in docs.text.lower()
    assert client.get("/redoc").status_code == 404


@pytest.mark.parametrize("content_type", [None, "text/plain"])
def test_a_json_body_without_its_content_type_is_told_what_to_send(client, content_type) -> None:
    head = {H: TECHNICIAN, **({"Content-Type": content_type} if content_type else {})}
    r = client.put("/api/v1/compensation/shadow", headers=head, content=b'{"shadow": true}')
    assert r.status_code == 415
    assert "Content-Type: application/json" in r.json()["detail"]
    assert (content_type or "no Content-Type") in r.json()["detail"]
    r = client.put("/api/v1/compensation/shadow", headers={H: TECHNICIAN},
                   json={"shadow": True})
    assert r.status_code == 200


def test_reading_needs_a_key_when_reading_is_not_open(tmp_path) -> None:
    from fastapi.testclient import TestClient

    from service.api.app import create_app
    from service.serve import Children, build
    from tests.unit.service.conftest import make_settings

    gauge, _ = build(make_settings(tmp_path, api={"open_read": False}), Children())
    with TestClient(create_app(gauge)) as c:
        assert c.get("/api/v1/status").status_code == 401
        assert c.get("/api/v1/status", headers={H: OPERATOR}).status_code == 200
        assert c.get("/healthz").status_code == 200


def test_master_correction_and_a_failed_check_block_offsets(client) -> None:
    before = client.get("/api/v1/measurements/latest").json()
    # A correction beyond measurement.max_correction_offset_mm (20 um) is refused.
    big = client.post("/api/v1/master/correction", headers={H: TECHNICIAN},
                      json={"masters": [{"certified_mm": 30.0, "measured_mm": 29.9}]})
    assert big.status_code == 422 and "max_correction" in big.json()["detail"], big.text
    assert client.get("/api/v1/master").json()["correction"] is None
    r = client.post("/api/v1/master/correction", headers={H: TECHNICIAN},
                    json={"masters": [{"certified_mm": 30.0, "measured_mm": 29.99}]})
    assert r.status_code == 200 and abs(r.json()["correction"]["offset_mm"] - 0.01) < 1e-9
    import time

    time.sleep(0.5)
    after = client.get("/api/v1/measurements/latest").json()
    assert after["seq"] > before["seq"]
    assert abs(after["diameter_mm"] - after["raw_diameter_mm"] - 0.01) < 1e-9
    # the correction is now wrong by 10 um: a master check fails, and offsets are blocked
    r = client.post("/api/v1/master/measure", headers={H: TECHNICIAN},
                    json={"certified_mm": 30.0, "frames": 5})
    assert r.status_code == 200 and r.json()["check"]["passed"] is False
    # While the master was measured no measurement counted for compensation.
    held = client.get("/api/v1/compensation/log", params={"kinds": "refused"}).json()["items"]
    assert any(x["code"] == "status_held_for_master" for x in held), held
    assert client.get("/api/v1/status").json()["compensation"]["held"] is None  # released
    status = client.get("/api/v1/master").json()
    assert status["blocking"] and "failed" in status["blocking"]
    time.sleep(0.5)
    problems = client.get("/api/v1/status").json()["problems"]
    assert "offsets_blocked" in [p["code"] for p in problems], problems
    assert any("failed" in p["text"] for p in problems if p["code"] == "offsets_blocked")
    assert all(ch.controller.writes_blocked for _, ch in client.gauge.compensation.in_force())
    # two masters of equal size cannot give a scale
    bad = client.post("/api/v1/master/correction", headers={H: TECHNICIAN},
                      json={"masters": [{"certified_mm": 30.0, "measured_mm": 30.0},
                                        {"certified_mm": 30.5, "measured_mm": 30.5}]})
    assert bad.status_code == 422 and "differ" in bad.json()["detail"]


def test_an_id_beyond_64_bits_is_a_malformed_request(client) -> None:
    for path in ("/api/v1/calibrations/40891108549731607904256",
                 "/api/v1/calibrations/40891108549731607904256/export"):
        r = client.get(path)
        assert r.status_code == 422, (path, r.text)


def test_a_record_with_non_finite_figures_is_still_json() -> None:
    import json
    import math

    from service.runtime import MeasurementRecord

    rec = MeasurementRecord(
        seq=1, time=0.0, frame_id=1, method="axis", status="fit_failed", diameter_mm=None,
        raw_diameter_mm=None, uncertainty_mm=math.inf, diameter_20c_mm=None,
        fused_diameter_mm=None, fused_uncertainty_mm=None, deviation_mm=None,
        in_tolerance=None, arc_deg=math.nan, n_points=12, rms_residual_mm=math.nan,
        latency_ms=3.0, reason="fit failed", note="")
    d = rec.as_dict()
    assert d["arc_deg"] is None and d["rms_residual_mm"] is None and d["uncertainty_mm"] is None
    assert d["latency_ms"] == 3.0
    json.loads(json.dumps(d, allow_nan=False))



def test_the_predictive_law_is_chosen_over_the_api(client) -> None:
    r = client.put("/api/v1/compensation", headers={H: ADMIN},
                   json={"law": "predictive", "gain": 0.4, "trend_gain": 0.2})
    assert r.status_code == 200, r.text
    s = client.gauge.compensation.in_force()[0][1].controller.settings
    assert (s.law, s.gain, s.trend_gain) == ("predictive", 0.4, 0.2)
    bad = client.put("/api/v1/compensation", headers={H: ADMIN}, json={"law": "pid"})
    assert bad.status_code == 422 and "law" in bad.text
