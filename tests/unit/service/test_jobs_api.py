"""Jobs over the API on the simulated rig: a two-feature part measured feature by feature,
recorded part by part, each tool with its compensation of its own, diameters that fit no
feature refused with a reason."""

from __future__ import annotations

import json
import time

import pytest
from pymodbus.client import ModbusTcpClient

from drivers.plc.registers import BY_NAME
from tests.aqdef_reading import characteristics
from tests.unit.service.conftest import OPERATOR, TECHNICIAN

H = {"X-API-Key": TECHNICIAN}
TWO = {"part_number": "SH-4711", "name": "two steps", "features": [
    {"number": 1, "name": "journal", "nominal_mm": 30.0, "tol_upper_mm": 0.05,
     "tol_lower_mm": -0.05, "tool": 1},
    {"number": 2, "name": "seat", "nominal_mm": 25.0, "tol_upper_mm": 0.05,
     "tol_lower_mm": -0.05, "tool": 2}]}


def latest_with(client, predicate, timeout_s: float = 20.0) -> dict:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        m = client.get("/api/v1/measurements/latest").json()
        if predicate(m):
            return m
        time.sleep(0.05)
    raise AssertionError(f"no such measurement: last {m}")


def test_a_two_feature_part_is_measured_feature_by_feature_and_recorded(client, tmp_path
                                                                        ) -> None:
    r = client.post("/api/v1/jobs", headers=H, json={"document": TWO, "activate": True,
                                                     "note": "from the drawing"})
    assert r.status_code == 201, r.text
    job = r.json()
    assert job["version"] == 1 and job["active"] and job["created_by"].startswith("technician")
    st = client.get("/api/v1/status").json()["job"]
    assert st["job"]["features"] == 2 and st["offsets_held"] is None
    entries = client.get("/api/v1/status").json()["compensation"]["entries"]
    assert [(e["tool"], e["entry"], e["features"]) for e in entries] == [
        (1, None, [1]), (2, None, [2])]
    m = latest_with(client, lambda m: m["feature"] == 1 and m["status"] == "ok")
    assert abs(m["deviation_mm"]) < 0.01
    client.gauge.camera.diameter_mm = 25.0  # the laser on the seat
    m = latest_with(client, lambda m: m["feature"] == 2 and m["status"] == "ok")
    assert abs(m["deviation_mm"]) < 0.01 and m["in_tolerance"]
    client.gauge.camera.diameter_mm = 30.0  # the next part's journal
    latest_with(client, lambda m: m["feature"] == 1)
    deadline = time.monotonic() + 10
    while not (parts := [p for p in client.get("/api/v1/parts").json()["items"]
                         if p["serial"].startswith("SH-4711")]):
        assert time.monotonic() < deadline
        time.sleep(0.05)
    part = parts[-1]
    assert part["serial"] == "SH-4711-g1" and part["verdict"] == "ok"
    assert [(f["feature"], f["verdict"]) for f in part["features"]] == [(1, "ok"), (2, "ok")]
    assert abs(part["features"][1]["diameter_mm"] - 25.0) < 0.01
    metrics = client.get("/metrics").text
    seat = [ln for ln in metrics.splitlines()
            if ln.startswith('shaftgauge_feature_diameter_mm{feature="2",name="seat"} ')]
    assert seat and abs(float(seat[0].rsplit(" ", 1)[1]) - 25.0) < 0.01
    assert 'shaftgauge_parts_total{verdict="ok"}' in metrics
    labelled = [ln for ln in metrics.splitlines() if ln.startswith("shaftgauge_feature_")]
    assert len(labelled) <= 2 * 2  # two features of the job in force, two figures each
    dfq = client.get("/api/v1/export/aqdef/parts")
    assert dfq.status_code == 200 and "K1001/1 SH-4711" in dfq.text
    assert "K2002/2 seat" in dfq.text and "K0014/2 SH-4711-g1" in dfq.text
    # As an independent reader takes it: a characteristic a feature, its limits the job's,
    # its values the parts'.
    (tmp_path / "parts.dfq").write_bytes(dfq.content)
    declared, chars = characteristics(tmp_path / "parts.dfq")
    assert declared == len(chars) == 2
    exported = client.get("/api/v1/parts", params={"limit": 1000}).json()["items"]
    for c, f in zip(chars, TWO["features"], strict=True):
        assert (c["number"], c["description"]) == (str(f["number"]), f["name"])
        assert (c["lower"], c["upper"]) == pytest.approx(
            (f["nominal_mm"] + f["tol_lower_mm"], f["nominal_mm"] + f["tol_upper_mm"]))
        measured = [r["diameter_mm"] for p in exported if p["serial"].startswith("SH-4711")
                    for r in p["features"] if r["feature"] == f["number"]
                    and r["diameter_mm"] is not None]
        # (the list read after the file: a part may have finished in between)
        assert c["values"] and all(any(abs(v - m) <= 0.5e-4 for m in measured)
                                   for v in c["values"]), (c["values"], measured)
    # Two tools: each judged its own feature's parts (the seat's from 25 mm, not 30).
    log = client.get("/api/v1/compensation/log", params={"limit": 200}).json()["items"]
    judged = {(row["tool"], row["deviation_mm"] is not None and abs(row["deviation_mm"]) < 0.01)
              for row in log if row["measurement_seq"] is not None}
    assert {(1, True), (2, True)} <= judged, log[:5]
    assert not [r for r in log if "held_for" in r["code"] + r["reason"]], log[:5]
    # One tool reset, by its number; a tool the job lacks is named in the refusal.
    r = client.post("/api/v1/compensation/command", headers=H,
                    json={"command": "reset", "tool": 2})
    assert r.status_code == 200 and r.json()["decision"]["tool"] == 2, r.text
    r = client.post("/api/v1/compensation/command", headers=H,
                    json={"command": "reset", "tool": 3})
    assert r.status_code == 404 and "has tools [1, 2]" in r.json()["detail"]
    # An insert change names its tool in a job of several; it is a reset, logged as such.
    r = client.post("/api/v1/compensation/command", headers=H,
                    json={"command": "insert_change"})
    assert r.status_code == 422 and "names the tool" in r.json()["detail"], r.text
    r = client.post("/api/v1/compensation/command", headers={"X-API-Key": OPERATOR},
                    json={"command": "insert_change", "tool": 1})
    assert r.status_code == 403
    r = client.post("/api/v1/compensation/command", headers=H,
                    json={"command": "insert_change", "tool": 1})
    d = r.json()["decision"]
    assert r.status_code == 200 and (d["code"], d["tool"], d["kind"]) == (
        "insert_change", 1, "reset"), r.text


ONE_TOOL = {"part_number": "SH-1T", "name": "two steps, one tool", "features": [
    {"number": 1, "name": "journal", "nominal_mm": 30.0, "tol_upper_mm": 0.05,
     "tol_lower_mm": -0.05, "tool": 1},
    {"number": 2, "name": "seat", "nominal_mm": 25.0, "tol_upper_mm": 0.02,
     "tol_lower_mm": -0.02, "tool": 1}]}


def test_a_job_one_tool_finishes_is_compensated_feature_by_feature(client) -> None:
    """Each measurement is judged against its own feature and goes into the one tool's law:
    nothing is held for the job, and the seat's deviation is from 25 mm, not 30."""
    r = client.post("/api/v1/jobs", headers=H, json={"document": ONE_TOOL, "activate": True})
    assert r.status_code == 201, r.text
    assert client.get("/api/v1/status").json()["job"]["offsets_held"] is None
    client.gauge.camera.diameter_mm = 25.012
    deadline, rows = time.monotonic() + 20, []
    while time.monotonic() < deadline:
        rows = client.get("/api/v1/compensation/log", params={"limit": 200}).json()["items"]
        seat = [r for r in rows if r.get("deviation_mm") is not None
                and abs(r["deviation_mm"] - 0.012) < 0.004]
        if seat:
            break
        time.sleep(0.1)
    assert seat, rows[:5]
    assert not [r for r in rows if "held_for" in r["code"] + r["reason"]], rows[:5]


def test_a_diameter_that_fits_no_feature_is_refused_with_a_reason(client) -> None:
    client.post("/api/v1/jobs", headers=H, json={"document": TWO, "activate": True})
    client.gauge.camera.diameter_mm = 35.0
    m = latest_with(client, lambda m: m["diameter_mm"] and m["diameter_mm"] > 34.0)
    assert m["feature"] is None and m["deviation_mm"] is None and m["in_tolerance"] is None
    assert "fits no feature" in m["reason"] and "30 mm" in m["reason"]
    assert "fits no feature" in client.get("/api/v1/status").json()["job"]["last_refused"]


def test_the_feature_under_the_laser_named_and_a_feature_the_job_lacks_refused(client) -> None:
    client.post("/api/v1/jobs", headers=H, json={"document": TWO, "activate": True})
    r = client.put("/api/v1/jobs/feature", headers=H, json={"feature": 7})
    assert r.status_code == 422 and "feature 7 is not in job 'SH-4711'" in r.json()["detail"]
    assert client.put("/api/v1/jobs/feature", headers={"X-API-Key": OPERATOR},
                      json={"feature": 2}).status_code == 403
    assert client.put("/api/v1/jobs/feature", headers=H,
                      json={"feature": 2}).json()["feature_selected"] == 2
    m = latest_with(client, lambda m: m["feature"] == 2)  # the journal, taken as the seat
    assert m["in_tolerance"] is False and abs(m["deviation_mm"] - 5.0) < 0.01
    client.put("/api/v1/jobs/feature", headers=H, json={"feature": None})
    latest_with(client, lambda m: m["feature"] == 1)


def test_a_bad_job_is_refused_naming_the_field_and_versions_are_kept(client) -> None:
    bad = {**TWO, "features": [dict(TWO["features"][0], tool=0)]}
    r = client.post("/api/v1/jobs", headers=H, json={"document": bad})
    assert r.status_code == 422 and "features[0].tool" in r.json()["detail"]
    assert client.post("/api/v1/jobs", headers={"X-API-Key": OPERATOR},
                       json={"document": TWO}).status_code == 403
    first = client.post("/api/v1/jobs", headers=H, json={"document": TWO}).json()
    second = client.post("/api/v1/jobs", headers=H, json={"document": TWO}).json()
    assert (first["version"], second["version"]) == (1, 2) and not second["active"]
    assert client.get(f"/api/v1/jobs/{second['id']}").json()["document"]["part_number"] == \
        "SH-4711"
    assert client.get("/api/v1/jobs/999").status_code == 404
    assert client.get("/api/v1/export/aqdef/parts").status_code == 409  # none in force
    assert client.get("/api/v1/export/aqdef/parts?job=999").status_code == 404
    assert client.post("/api/v1/jobs/999/activate", headers=H).status_code == 404
    actions = [a["action"] for a in client.get("/api/v1/jobs/audit").json()["items"]]
    assert actions == ["add", "add"]


def test_a_one_feature_job_is_the_feature_and_a_direct_one_ends_it(client) -> None:
    """The job is the only source of features: a stored job of one feature is what the API
    and the registers show, and the settings keep their own single feature (no write into
    them: one path for every job)."""
    before = client.get("/api/v1/compensation").json()["settings"]["nominal_mm"]
    one = {**TWO, "part_number": "PIN-1", "features": [dict(TWO["features"][0],
                                                           nominal_mm=30.002)]}
    jid = client.post("/api/v1/jobs", headers=H, json={"document": one}).json()["id"]
    assert client.post(f"/api/v1/jobs/{jid}/activate", headers=H).status_code == 200
    assert client.get("/api/v1/feature").json()["nominal_mm"] == 30.002
    assert client.get("/api/v1/compensation").json()["settings"]["nominal_mm"] == before
    assert client.gauge.modbus.bank.get("nominal") == 300020
    assert client.get("/api/v1/status").json()["job"]["offsets_held"] is None
    # A feature set directly (as a map-v3 CNC does) ends the stored job.
    client.put("/api/v1/feature", headers=H, json={"nominal_mm": 30.0, "tol_upper_mm": 0.02,
                                                   "tol_lower_mm": -0.02})
    st = client.get("/api/v1/status").json()["job"]
    assert st["job"]["id"] is None and st["job"]["part_number"] == "single feature"
    assert client.get("/api/v1/jobs").json()["items"][0]["active"] is False


def test_activating_a_one_feature_job_over_another_rebuilds_once(client) -> None:
    """The job before is not ended by a feature set directly (the store's audit) and the
    gauge's parts hear of one new job, not two."""
    jobs = client.gauge.jobs
    new_jobs: list[str] = []
    jobs.on_new_job(lambda: new_jobs.append(jobs.job.part_number if jobs.job else ""))
    two = client.post("/api/v1/jobs", headers=H, json={"document": TWO, "activate": True})
    assert two.status_code == 201, two.text
    one = {**TWO, "part_number": "PIN-1", "features": [dict(TWO["features"][0],
                                                           nominal_mm=30.002)]}
    new_jobs.clear()
    r = client.post("/api/v1/jobs", headers=H, json={"document": one, "activate": True})
    assert r.status_code == 201, r.text
    assert new_jobs == ["PIN-1"]
    actions = [a["action"] for a in jobs.store.audit()]
    assert "deactivate" not in actions, actions
    assert client.get("/api/v1/feature").json()["nominal_mm"] == 30.002


def test_the_cnc_puts_a_job_in_force_names_the_feature_and_counts_parts(client) -> None:
    """Register map version 4 over real Modbus: what the job does not have is refused whole
    (exception 0x03, nothing changed)."""
    jid = client.post("/api/v1/jobs", headers=H, json={"document": TWO}).json()["id"]
    job, feature, counter = (BY_NAME[n].address for n in ("job", "feature", "part_counter"))
    with ModbusTcpClient("127.0.0.1", port=client.gauge.modbus.port, retries=0) as c:
        refused = c.write_registers(job, [999, 1], device_id=1)
        assert refused.isError() and refused.exception_code == 3
        assert c.read_holding_registers(job, count=2, device_id=1).registers == [0, 0]
        assert not c.write_registers(job, [jid, 2], device_id=1).isError()
        deadline = time.monotonic() + 5
        while c.read_holding_registers(job, count=2, device_id=1).registers != [jid, 2]:
            assert time.monotonic() < deadline
            time.sleep(0.05)
        st = client.get("/api/v1/status").json()["job"]
        assert st["job"]["id"] == jid and st["feature_selected"] == 2
        # A revision keeps the job's number: the program writes the same, the newest goes in
        # force, the register reads the number; a later version's id is no job's number.
        revised = client.post("/api/v1/jobs", headers=H, json={"document": TWO}).json()
        assert revised["version"] == 2 and revised["number"] == jid, revised
        assert not c.write_registers(job, [jid, 2], device_id=1).isError()
        deadline = time.monotonic() + 5
        while client.get("/api/v1/status").json()["job"]["job"]["id"] != revised["id"]:
            assert time.monotonic() < deadline
            time.sleep(0.05)
        assert c.read_holding_registers(job, count=2, device_id=1).registers == [jid, 2]
        bad = c.write_register(job, revised["id"], device_id=1)
        assert bad.isError() and bad.exception_code == 3
        bad = c.write_register(feature, 7, device_id=1)
        assert bad.isError() and bad.exception_code == 3
        assert c.read_holding_registers(feature, count=1, device_id=1).registers == [2]
        tool = BY_NAME["cnc_tool"].address  # a pull report for a tool the job lacks
        bad = c.write_register(tool, 3, device_id=1)
        assert bad.isError() and bad.exception_code == 3
        assert c.read_holding_registers(tool, count=1, device_id=1).registers == [0]
        assert not c.write_register(tool, 2, device_id=1).isError()
        entry = BY_NAME["cnc_entry"].address  # and for an offset entry it lacks
        bad = c.write_registers(entry, [12, 5], device_id=1)
        assert bad.isError() and bad.exception_code == 3
        assert c.read_holding_registers(entry, count=2, device_id=1).registers == [0, 0]
        assert not c.write_registers(entry, [0, 5], device_id=1).isError()  # a tool's own
        assert not c.write_register(feature, 0, device_id=1).isError()  # recognise again
        assert not c.write_register(counter, 41, device_id=1).isError()
        latest_with(client, lambda m: m["feature"] == 1)
        time.sleep(0.3)
        assert not c.write_register(counter, 42, device_id=1).isError()  # the next part
        latest_with(client, lambda m: m["feature"] == 1 and m["seq"] > 0)
        deadline = time.monotonic() + 10
        while not [p for p in client.get("/api/v1/parts").json()["items"]
                   if p["serial"] == "SH-4711-41"]:
            assert time.monotonic() < deadline
            time.sleep(0.05)
        assert not c.write_register(job, 0, device_id=1).isError()  # back to one feature
    deadline = time.monotonic() + 5
    while client.get("/api/v1/status").json()["job"]["job"]["id"] is not None:
        assert time.monotonic() < deadline
        time.sleep(0.05)


def test_a_gauge_study_of_a_features_master_takes_its_tolerance(client) -> None:
    client.post("/api/v1/jobs", headers=H, json={"document": TWO, "activate": True})
    r = client.post("/api/v1/gauge-studies", headers=H,
                    json={"certified_mm": 30.0, "n": 25, "feature": 7})
    assert r.status_code == 422 and "feature 7 is not in job" in r.json()["detail"]
    r = client.post("/api/v1/gauge-studies", headers=H,
                    json={"certified_mm": 30.0, "n": 25, "feature": 1})
    assert r.status_code == 202, r.text
    assert r.json()["tolerance_mm"] == 0.1 and r.json()["feature"] == 1
    assert client.get("/api/v1/gauge-studies").json()["items"][0]["feature"] == 1


def test_another_setting_leaves_the_job_and_its_spc_as_they_were(client) -> None:
    """Shadow mode or tuning is no new feature: the part under way and the charts stay."""
    jobs, spc = client.gauge.jobs, client.gauge.spc
    latest_with(client, lambda m: m["feature"] == 1 and m["status"] == "ok")
    job, parts = jobs.job, jobs.parts
    deadline = time.monotonic() + 10
    while not spc.monitors:
        assert time.monotonic() < deadline
        time.sleep(0.05)
    assert client.put("/api/v1/compensation/shadow", headers=H,
                      json={"shadow": False}).status_code == 200
    assert jobs.job is job and jobs.parts is parts and spc.monitors
    client.put("/api/v1/feature", headers=H, json={"nominal_mm": 30.001, "tol_upper_mm": 0.02,
                                                   "tol_lower_mm": -0.02})
    assert jobs.job is not job and jobs.job.features[0].nominal_mm == 30.001


def test_a_job_the_controller_cannot_take_is_refused_whole_and_the_last_stays(client) -> None:
    """The second outside probe: a tool's trend gain of 1 passed the job's check and not the
    controller's, so the store marked the job active, the request answered 500 and the
    gauge could no longer start. One bound now, checked before anything is stored."""
    first = client.post("/api/v1/jobs", headers=H, json={"document": TWO, "activate": True})
    assert first.status_code == 201, first.text
    bad = {**TWO, "tools": [{"number": 2, "trend_gain": 1.0}]}
    r = client.post("/api/v1/jobs", headers=H, json={"document": bad, "activate": True})
    assert r.status_code == 422 and "tools[0].trend_gain" in r.json()["detail"], r.text
    st = client.get("/api/v1/status").json()
    assert st["job"]["job"]["id"] == first.json()["id"]
    assert [e["tool"] for e in st["compensation"]["entries"]] == [1, 2]
    assert [j["active"] for j in client.get("/api/v1/jobs").json()["items"]] == [True]
    for text in ("SH\r1", "SH\x001", "\ud800"):  # JSON escapes it: a lone surrogate too
        body = json.dumps({"document": {**TWO, "part_number": text}})
        r = client.post("/api/v1/jobs", headers={**H, "Content-Type": "application/json"},
                        content=body)
        assert r.status_code == 422 and "part_number" in r.json()["detail"], r.text


def test_a_job_on_offset_entries_is_taken_and_each_entry_reported(client) -> None:
    """A feature on an offset entry of its own: the job is stored and in force, its entry
    has its own compensation, named as the CNC names it, in the status and /metrics."""
    doc = {**TWO, "features": [*TWO["features"], dict(
        TWO["features"][1], number=3, name="pin", nominal_mm=20.0, entry=12)]}
    r = client.post("/api/v1/jobs", headers=H, json={"document": doc, "activate": True})
    assert r.status_code == 201, r.text
    entries = client.get("/api/v1/status").json()["compensation"]["entries"]
    assert [(e["tool"], e["entry"], e["features"]) for e in entries] == [
        (1, None, [1]), (2, None, [2]), (2, 12, [3])]
    metrics = client.get("/metrics").text
    assert 'shaftgauge_cumulative_offset_mm{entry="12",tool="2"}' in metrics, metrics[-800:]
    bad = {**doc, "features": [*doc["features"][:2], dict(doc["features"][2], entry=70000)]}
    r = client.post("/api/v1/jobs", headers=H, json={"document": bad})
    assert r.status_code == 422 and "features[2].entry" in r.json()["detail"], r.text


def test_a_start_on_a_stored_job_it_cannot_take_falls_back_and_says_so(tmp_path) -> None:
    """A job an older release stored and put in force, which this one refuses: the gauge
    starts on the settings' single feature, says why, and a technician ends the job."""
    import sqlite3

    from fastapi.testclient import TestClient

    from service.api.app import create_app
    from service.serve import Children, build
    from tests.unit.service.conftest import make_settings

    settings = make_settings(tmp_path)
    gauge, _ = build(settings, Children())
    with TestClient(create_app(gauge)) as c:
        jid = c.post("/api/v1/jobs", headers=H, json={"document": TWO, "activate": True}
                     ).json()["id"]
    bad = {**TWO, "tools": [{"number": 2, "trend_gain": 1.0}]}
    with sqlite3.connect(settings.store.path) as db:  # as the older release stored it
        db.execute("UPDATE jobs SET document = ? WHERE id = ?", (json.dumps(bad), jid))
    gauge, _ = build(settings, Children())
    with TestClient(create_app(gauge)) as c:
        st = c.get("/api/v1/status").json()
        assert st["job"]["job"]["part_number"] == "single feature", st["job"]
        assert any("trend_gain" in p["text"] for p in st["problems"]), st["problems"]
        assert c.delete("/api/v1/jobs/active", headers=H).status_code == 200
        assert not any(j["active"] for j in c.get("/api/v1/jobs").json()["items"])


def test_tuning_the_job_in_force_cannot_hold_is_refused_naming_the_feature(client) -> None:
    """A null band of 15 um against a feature of +-12 um was taken, and after a restart the
    job read as damaged and compensation stopped (the second outside probe)."""
    from tests.unit.service.conftest import ADMIN

    tight = {**TWO, "features": [TWO["features"][0],
                                 dict(TWO["features"][1], tol_upper_mm=0.012,
                                      tol_lower_mm=-0.012)]}
    assert client.post("/api/v1/jobs", headers=H,
                       json={"document": tight, "activate": True}).status_code == 201
    r = client.put("/api/v1/compensation", headers={"X-API-Key": ADMIN},
                   json={"deadband_mm": 0.015})
    assert r.status_code == 422 and "feature 2 (seat)" in r.json()["detail"], r.text
    assert client.get("/api/v1/compensation").json()["settings"]["deadband_mm"] != 0.015
    r = client.put("/api/v1/compensation", headers={"X-API-Key": ADMIN},
                   json={"deadband_mm": 0.005})
    assert r.status_code == 200, r.text


NO_VALUE_UM = -214748364.8


def test_the_part_program_reads_each_features_result_and_the_parts_verdict(client) -> None:
    """Register map version 5 over real Modbus, as a part program uses it: name a feature and
    ask for it measured, wait for the answer, read the verdicts; a part with a feature out
    says so; a request the gauge cannot measure is answered refused, with its reason."""
    client.post("/api/v1/jobs", headers=H, json={"document": TWO, "activate": True})
    a = {n: r.address for n, r in BY_NAME.items()}

    def read(c, name: str, count: int = 1) -> list[int]:
        return c.read_holding_registers(a[name], count=count, device_id=1).registers

    def measured(c, seq: int, feature: int) -> dict[str, int]:
        # As the manual says: 0 first, until the gauge says it has forgotten the last one.
        assert not c.write_register(a["measure_request"], 0, device_id=1).isError()
        deadline = time.monotonic() + 20
        while read(c, "measured_seq") != [0]:
            assert time.monotonic() < deadline, "measure_request 0 not taken"
            time.sleep(0.05)
        assert not c.write_registers(a["measure_feature"], [feature, seq],
                                     device_id=1).isError()
        while read(c, "measured_seq") != [seq]:
            assert time.monotonic() < deadline, f"request {seq} not answered"
            time.sleep(0.05)
        words = read(c, "measured_seq", 14)
        value = (words[4] << 16 | words[5])
        return {"feature": words[1], "verdict": words[2], "reason": words[3],
                "value_um": (value - (1 << 32) if value & 0x80000000 else value) / 10,
                "part_verdict": words[10], "part": words[11]}

    with ModbusTcpClient("127.0.0.1", port=client.gauge.modbus.port, retries=0) as c:
        # Half a request, a feature the job lacks: refused whole.
        assert c.write_register(a["measure_request"], 1, device_id=1).isError()
        bad = c.write_registers(a["measure_feature"], [7, 1], device_id=1)
        assert bad.isError() and bad.exception_code == 3
        assert not c.write_register(a["part_counter"], 7, device_id=1).isError()
        journal = measured(c, 1, 1)
        assert (journal["feature"], journal["verdict"], journal["reason"]) == (1, 1, 0)
        assert abs(journal["value_um"] - 30000.0) < 10 and journal["part"] == 7
        assert journal["part_verdict"] == 0  # the seat is not measured yet
        assert read(c, "features") == [2] and read(c, "feature1_number", 4) == [1, 1, 0, 7]
        assert read(c, "feature2_number", 2) == [2, 0]
        client.gauge.camera.diameter_mm = 25.0  # the seat under the laser
        seat = measured(c, 2, 2)
        assert (seat["verdict"], seat["part_verdict"], seat["part"]) == (1, 1, 7), seat
        assert read(c, "feature2_number", 4) == [2, 1, 0, 7]
        # The next part: its seat 90 um over (tolerance +-50): the part is out.
        # The journal under the laser before the counter moves on: frames of the seat
        # counted into part 8 would make it whole (a loaded suite's run did).
        client.gauge.camera.diameter_mm = 30.0
        latest_with(client, lambda m: m["feature"] == 1 and m["status"] == "ok")
        assert not c.write_register(a["part_counter"], 8, device_id=1).isError()
        assert measured(c, 3, 1)["part_verdict"] == 0
        client.gauge.camera.diameter_mm = 25.09
        out = measured(c, 4, 2)
        assert (out["verdict"], out["part_verdict"], out["part"]) == (2, 2, 8), out
        assert abs(out["value_um"] - 25090.0) < 10
        # The journal asked for while the seat is under the laser: refused, as another
        # feature's diameter, in its time.
        other = measured(c, 5, 1)
        assert (other["verdict"], other["reason"], other["value_um"]) == (3, 10, NO_VALUE_UM)
        # No frame comes (the camera unplugged): refused, nothing measured.
        client.gauge.camera.unplug()
        time.sleep(0.5)
        try:
            away = measured(c, 6, 1)
        finally:
            client.gauge.camera.plug()
        assert (away["verdict"], away["reason"]) == (3, 1), away
        # The journal of part 8 was measured before: its block keeps that result; a
        # feature answered refused and not measured since would read 3 and its reason.
        assert read(c, "feature1_verdict", 2) == [1, 0]
    parts = client.get("/api/v1/parts").json()["items"]
    assert [p["verdict"] for p in parts if p["serial"] == "SH-4711-7"] == ["ok"]
