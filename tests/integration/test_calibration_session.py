"""A calibration session through the API, from uploaded images to an active calibration."""

from __future__ import annotations

from tests.unit.service.conftest import OPERATOR, TECHNICIAN
from tests.waiting import until

H = {"X-API-Key": TECHNICIAN}
STEP_DEADLINE_S = 600.0
"""A step of 25 views takes half a minute of CPU; six workers share two cores in the suite."""


def wait_done(client, sid, step, timeout_s=STEP_DEADLINE_S):
    """The session once ``step`` has ended (done or failed)."""
    def ended():
        s = client.get(f"/api/v1/calibration-sessions/{sid}").json()
        return s if (s["progress"]["step"] == step
                     and s["progress"]["state"] in ("done", "failed")) else None
    return until(ended, f"step {step} ended", timeout_s, step_s=0.2)


def upload(client, sid, kind, path):
    r = client.post(f"/api/v1/calibration-sessions/{sid}/images/{kind}", headers=H,
                    content=path.read_bytes())
    assert r.status_code == 201, r.text


def test_session_from_upload_to_activation(client, calibration_images) -> None:
    r = client.post("/api/v1/calibration-sessions", headers=H, json={"note": "monday"})
    assert r.status_code == 201
    sid = r.json()["id"]
    # A capture holds offsets (the camera looks at a board); the live frame here is a shaft,
    # which the intrinsics step sets aside as an image without a board.
    assert client.post(f"/api/v1/calibration-sessions/{sid}/capture/view",
                       headers=H).status_code == 201
    assert sid in client.get("/api/v1/status").json()["compensation"]["held"]
    for p in sorted((calibration_images / "views").glob("*.png")):
        upload(client, sid, "view", p)
    for i in range(4):
        upload(client, sid, "plane_off", calibration_images / "plane" / f"pose{i}_off.png")
        upload(client, sid, "plane_on", calibration_images / "plane" / f"pose{i}_on.png")
    for p in sorted((calibration_images / "axis").glob("*.png")):
        upload(client, sid, "axis", p)
    for step in ("intrinsics", "plane", "axis", "build"):
        assert client.post(f"/api/v1/calibration-sessions/{sid}/run/{step}",
                           headers=H).status_code == 202
        s = wait_done(client, sid, step)
        assert s["progress"]["state"] == "done", s["progress"]
    assert s["report"]["verdict"] in ("good", "marginal")
    r = client.post(f"/api/v1/calibration-sessions/{sid}/activate", headers=H,
                    json={"note": "from the session"})
    assert r.status_code == 200
    cid = r.json()["activated_id"]
    assert r.json()["counts"] is False  # an activated session holds no open place
    cal = client.get(f"/api/v1/calibrations/{cid}").json()
    assert cal["active"] and cal["quality"]["verdict"] == s["report"]["verdict"]
    assert client.get("/api/v1/status").json()["compensation"]["held"] is None


def test_bad_sessions_are_refused(client, calibration_images) -> None:
    sid = client.post("/api/v1/calibration-sessions", headers=H, json={}).json()["id"]
    assert client.post("/api/v1/calibration-sessions", headers=H,
                       json={"board": "banana"}).status_code == 422
    r = client.post(f"/api/v1/calibration-sessions/{sid}/images/view", headers=H,
                    content=b"not a picture")
    assert r.status_code == 415 and "PNG" in r.json()["detail"]  # not a PNG at all
    assert client.post(f"/api/v1/calibration-sessions/{sid}/images/colour", headers=H,
                       content=b"x").status_code == 422
    for p in sorted((calibration_images / "views").glob("*.png"))[:2]:
        upload(client, sid, "view", p)
    client.post(f"/api/v1/calibration-sessions/{sid}/run/intrinsics", headers=H)
    s = wait_done(client, sid, "intrinsics")
    assert s["progress"]["state"] == "failed" and "need 6" in s["progress"]["message"]
    r = client.post(f"/api/v1/calibration-sessions/{sid}/activate", headers=H, json={})
    assert r.status_code == 409 and "build" in r.json()["detail"]
    assert client.post(f"/api/v1/calibration-sessions/{sid}/capture/view",
                       headers={"X-API-Key": OPERATOR}).status_code == 403
    r = client.post(f"/api/v1/calibration-sessions/{sid}/capture/view", headers=H)
    assert r.status_code == 201 and r.json()["images"]["view"] == 3  # the live frame
    assert client.get("/api/v1/calibration-sessions/nope").status_code == 404


def test_every_session_endpoint_needs_a_technician_key_and_a_good_body(client) -> None:
    op = {"X-API-Key": OPERATOR}
    start = "/api/v1/calibration-sessions"
    assert client.post(start, json={}).status_code == 401
    assert client.post(start, headers=op, json={}).status_code == 403
    assert client.post(start, headers=H, json={"board": 5}).status_code == 422
    sid = client.post(start, headers=H, json={}).json()["id"]
    png = b"\x89PNG\r\n\x1a\n"  # a body that is no image: 422 once the key is right
    calls = [
        ("post", f"{start}/{sid}/images/view", {"content": png}, {"content": b""}),
        ("post", f"{start}/{sid}/capture/view", {}, None),
        ("post", f"{start}/{sid}/run/intrinsics", {}, None),
        ("post", f"{start}/{sid}/activate", {"json": {}}, {"json": {"note": 5}}),
    ]
    for method, path, good, bad in calls:
        call = getattr(client, method)
        assert call(path, **good).status_code == 401, path
        r = call(path, headers=op, **good)
        assert r.status_code == 403 and "technician" in r.json()["detail"], path
        if bad is not None:
            assert call(path, headers=H, **bad).status_code == 422, path
    for wrong in (f"{start}/{sid}/images/colour", f"{start}/{sid}/run/cook"):
        assert client.post(wrong, headers=H).status_code == 422


def test_a_fifth_session_opens_once_one_is_ended(client) -> None:
    start = "/api/v1/calibration-sessions"
    ids = [client.post(start, headers=H, json={}).json()["id"] for _ in range(4)]
    r = client.post(start, headers=H, json={})
    assert r.status_code == 409 and "DELETE" in r.json()["detail"]
    listed = client.get(start).json()
    assert {s["id"] for s in listed["items"]} >= set(ids) and listed["max_open"] == 4
    assert client.delete(f"{start}/{ids[0]}").status_code == 401
    assert client.delete(f"{start}/{ids[0]}",
                         headers={"X-API-Key": OPERATOR}).status_code == 403
    assert client.delete(f"{start}/{ids[0]}", headers=H).json() == {"ended": ids[0]}
    assert client.get(f"{start}/{ids[0]}").status_code == 404
    assert client.delete(f"{start}/{ids[0]}", headers=H).status_code == 404
    assert client.post(start, headers=H, json={}).status_code == 201
    # A failed step frees the place too (the technician may still add images and rerun it).
    client.post(f"{start}/{ids[1]}/run/intrinsics", headers=H)
    assert wait_done(client, ids[1], "intrinsics")["counts"] is False
    assert client.post(start, headers=H, json={}).status_code == 201
    # Ending a session that captured releases its hold on offsets.
    assert client.post(f"{start}/{ids[2]}/capture/view", headers=H).status_code == 201
    assert ids[2] in client.get("/api/v1/status").json()["compensation"]["held"]
    client.delete(f"{start}/{ids[2]}", headers=H)
    assert client.get("/api/v1/status").json()["compensation"]["held"] is None


def test_a_session_is_ended_while_its_step_runs(client) -> None:
    """A step on a board of 3600 corners in images of noise runs for many seconds; ending its
    session stops it (its worker process is killed) and frees the place."""
    import cv2
    import numpy as np

    start = "/api/v1/calibration-sessions"
    sid = client.post(start, headers=H, json={"board": "60x60x4"}).json()["id"]
    noise = np.random.default_rng(1).integers(0, 256, (1024, 1376), dtype=np.uint8)
    png = cv2.imencode(".png", noise)[1].tobytes()
    for _ in range(3):
        r = client.post(f"{start}/{sid}/images/view", headers=H, content=png)
        assert r.status_code == 201, r.text
    assert client.post(f"{start}/{sid}/run/intrinsics", headers=H).status_code == 202
    until(lambda: client.get(f"{start}/{sid}").json()["progress"]["message"]
          == "intrinsics: working", "the step running", step_s=0.1)
    assert client.delete(f"{start}/{sid}", headers=H).json() == {"ended": sid}
    assert client.get(f"{start}/{sid}").status_code == 404
    assert sid not in {s["id"] for s in client.get(start).json()["items"]}
