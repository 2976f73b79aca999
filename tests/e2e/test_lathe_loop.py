"""The loop closed through the whole service: ``shaftgauge serve`` measures what its simulated
camera shows, and the camera shows what a virtual lathe cuts with the simulated CNC's applied
total (read over Modbus); the offsets the gauge writes change what it sees a dead time later.
"""

from __future__ import annotations

import time

import httpx

from drivers.sim.control import control
from tests.e2e.conftest import TECH_KEY, start_service, stop_service, wait_ready

WEAR_UM_PER_MIN = 60.0   # 1 um a second: out of +-20 um in 20 s uncompensated
TOLERANCE_MM = 0.020

CAMERA = f"""sim_lathe = true
sim_drift_um_per_min = {WEAR_UM_PER_MIN}
sim_drift_period_min = 0
sim_lathe_dead_time_s = 1.0
sim_replay_frames = 8
"""
# The controller's dead time covers the lathe's (1 s), the camera's ring (8 frames rendered
# again after a change) and the window (5 measurements at 10/s).
COMPENSATION = f"""[compensation]
nominal_mm = 30.0
tol_upper_mm = {TOLERANCE_MM}
tol_lower_mm = -{TOLERANCE_MM}
window = 5
deadband_mm = 0.003
dead_time_measurements = 10
dead_time_s = 3.0
max_step_mm = 0.010
shadow = true
"""


def lathe(svc) -> dict:
    """The virtual lathe's sample under the laser now (the truth the gauge should see)."""
    return control(svc.control_port, {"get": "stats"})["stats"]["lathe"]


def follow(svc, seconds: float) -> list[dict]:
    """The lathe's truth, twice a second for ``seconds``."""
    out, deadline = [], time.monotonic() + seconds
    while time.monotonic() < deadline:
        out.append({**lathe(svc), "t": time.monotonic()})
        time.sleep(0.5)
    return out


def test_offsets_written_by_the_service_hold_the_cut_in_tolerance(tmp_path) -> None:
    svc = start_service(tmp_path, camera_toml=CAMERA, compensation_toml=COMPENSATION)
    try:
        assert wait_ready(svc)
        r = httpx.put(svc.url + "/api/v1/compensation/shadow", json={"shadow": False},
                      headers={"X-API-Key": TECH_KEY}, timeout=10)
        assert r.status_code == 200, r.text
        loop = follow(svc, 30.0)
        deviations_um = [round((s["cut_diameter_mm"] - 30.0) * 1000.0, 1) for s in loop]
        # What the camera shows follows the CNC: held in tolerance while the tool wears 30 um.
        assert loop[-1]["wear_mm"] - loop[0]["wear_mm"] > 0.025, loop[-1]
        assert max(abs(d) for d in deviations_um) < TOLERANCE_MM * 1000.0, deviations_um
        # The lathe's CNC total is the simulated PLC's applied total, which is the sum of the
        # gauge's applied offsets, each once.
        r = httpx.put(svc.url + "/api/v1/compensation/shadow", json={"shadow": True},
                      headers={"X-API-Key": TECH_KEY}, timeout=10)
        assert r.status_code == 200, r.text
        time.sleep(1.0)
        applied = svc.get("/api/v1/compensation/log", params={"kinds": "applied",
                                                              "limit": 1000}).json()["items"]
        assert applied and len({d["offset_seq"] for d in applied}) == len(applied)
        total = lathe(svc)["cnc_total_mm"]
        assert abs(sum(d["offset_mm"] for d in applied) - total) < 1e-6, (applied, total)
        assert abs(svc.get("/api/v1/status").json()["compensation"]["cnc_total_mm"]
                   - total) < 1e-6
        # Shadow mode from here: offsets proposed into the void, the CNC's total stays and
        # the tool wears the part out of tolerance.
        shadow = follow(svc, 24.0)
        worst_um = max(abs(s["cut_diameter_mm"] - 30.0) for s in shadow) * 1000.0
        print(f"\nFIGURES compensated 30 s: {min(deviations_um)}..{max(deviations_um)} um, "
              f"{len(applied)} offsets, CNC total {total * 1000:+.1f} um; then shadow 24 s: "
              f"worst {worst_um:.1f} um")
        assert all(s["cnc_total_mm"] == total for s in shadow)
        assert worst_um > TOLERANCE_MM * 1000.0, shadow[-1]
        assert svc.get("/api/v1/compensation/log",
                       params={"kinds": "proposed"}).json()["items"], "nothing proposed"
    finally:
        stop_service(svc)
