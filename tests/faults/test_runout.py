"""A part clamped off the spindle axis under compensation: its diameters are refused as not
concentric and no offset is written from them; the same part turned concentric, compensation
resumes. The simulated camera shows the surface going round (37 degrees of spindle a frame)."""

from __future__ import annotations

import time

from drivers.sim.control import control
from tests.e2e.conftest import start_service, stop_service, wait_ready
from tests.faults.test_service_faults import applied_in, until

OFF_AXIS = {"eccentricity_mm": 0.05, "eccentricity_deg": 30.0, "spindle_deg_per_frame": 37.0}


def test_a_part_clamped_off_the_axis_holds_offsets_until_it_runs_true(tmp_path) -> None:
    svc = start_service(tmp_path)
    plc_log = svc.data / "sim-plc.log"
    try:
        assert wait_ready(svc)
        # 12 um oversize (beyond the 4 um dead band) and 50 um off the spindle axis at once.
        reply = control(svc.control_port, {"set": {"turning": OFF_AXIS, "diameter_mm": 30.012}})
        assert reply["ok"], reply
        until(lambda: "not_concentric" in [p["code"] for p in svc.get(
            "/api/v1/status").json()["problems"]], 20, "the run-out said as a problem")
        time.sleep(12.0)  # long enough for offsets at the test's tuning (window 5, 10/s)
        assert applied_in(plc_log) == [], "an offset was written from an off-axis surface"
        latest = svc.get("/api/v1/measurements/latest").json()
        assert latest["status"] in ("not_concentric", "uncertain"), latest
        items = svc.get("/api/v1/compensation/log", params={"limit": 200}).json()["items"]
        held = [d for d in items if d.get("code") == "status_not_concentric"]
        assert held, [(d["kind"], d.get("code")) for d in items[:10]]
        assert not [d for d in items if d["kind"] in ("write", "applied")]
        problem = next(p for p in svc.get("/api/v1/status").json()["problems"]
                       if p["code"] == "not_concentric")
        assert "not concentric with the spindle axis" in problem["text"]

        # Turned true: the same oversize now measured, and corrected.
        assert control(svc.control_port, {"set": {"turning": {}}})["ok"]
        events = until(lambda: applied_in(plc_log), 40, "an offset applied once concentric")
        assert -100 <= events[0]["value_units"] < -40, events[0]
        assert "not_concentric" not in [p["code"] for p in svc.get(
            "/api/v1/status").json()["problems"]]
    finally:
        stop_service(svc)
