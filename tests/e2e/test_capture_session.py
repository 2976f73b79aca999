"""A calibration session captured from the live simulated GigE camera: the camera is shown
the board shot by shot (as a technician would hold it), the service captures each, and the
intrinsics come out of the captured frames. Offsets are held while it captures."""

from __future__ import annotations

import time

import httpx

from drivers.sim.control import control
from tests.e2e.conftest import TECH_KEY

H = {"X-API-Key": TECH_KEY}
SHOTS = ["view_00", "view_02", "view_04", "view_08", "view_12", "view_16", "view_20",
         "view_26"]


def show(svc, shot: str) -> None:
    """Point the simulated camera at the shot and wait until it streams it: the second frame
    rendered after the request is the shot (the one being rendered may be the old scene)."""
    reply = control(svc.control_port, {"show": {"shot": shot}})
    assert reply["ok"], reply
    start = reply["stats"]["rendered"]
    deadline = time.monotonic() + 20
    while control(svc.control_port, {"get": "stats"})["stats"]["rendered"] < start + 2:
        assert time.monotonic() < deadline, "the simulated camera did not show the shot"
        time.sleep(0.05)
    time.sleep(0.3)  # three frame periods: it has left the camera


def test_capture_session_from_the_live_camera(service) -> None:
    url = service.url + "/api/v1"
    sid = httpx.post(url + "/calibration-sessions", headers=H,
                     json={"note": "capture"}).json()["id"]
    for shot in SHOTS:
        show(service, shot)
        r = httpx.post(f"{url}/calibration-sessions/{sid}/capture/view", headers=H, timeout=10)
        assert r.status_code == 201, r.text
        assert r.json()["size"] == [1376, 1024]
    status = service.get("/api/v1/status").json()
    assert "capturing" in status["compensation"]["held"]
    assert "offsets_held" in [p["code"] for p in service.get("/readyz").json()["problems"]]
    assert httpx.post(f"{url}/calibration-sessions/{sid}/run/intrinsics", headers=H,
                      timeout=10).status_code == 202
    deadline = time.monotonic() + 120
    while True:
        s = service.get(f"/api/v1/calibration-sessions/{sid}").json()
        if s["progress"]["state"] in ("done", "failed"):
            break
        assert time.monotonic() < deadline
        time.sleep(0.3)
    assert s["progress"]["state"] == "done", s["progress"]
    result = s["results"]["intrinsics"]
    assert result["ok"] and result["images_used"] == len(SHOTS) and result["rejected"] == {}
    # Back to the shaft: it measures again, and nothing was written meanwhile.
    assert control(service.control_port, {"show": "shaft"})["stats"]["scene"] == "shaft"
    held = service.get("/api/v1/compensation/log", params={"kinds": "refused"}).json()["items"]
    assert any("held_for_calibration" in d["reason"] for d in held), held[:3]
    assert service.get("/api/v1/compensation/log",
                       params={"kinds": "write"}).json()["items"] == []
