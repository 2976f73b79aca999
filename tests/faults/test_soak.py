"""Soak: the service at the camera's full rate with periodic faults (packet loss, the PLC away,
the camera away), sampling the service process's RSS, open file descriptors and threads, and
the queue drops. `make test` runs one fault of each kind (about 40 s); `make soak` runs an hour
(``SHAFTGAUGE_SOAK_S`` changes it) and writes bench-results/soak.json."""

from __future__ import annotations

import json
import os
import statistics
import time
from pathlib import Path

import pytest

from drivers.sim.control import control
from tests.e2e.conftest import stop_service
from tests.faults.test_service_faults import Rig, start_rig, until

SAMPLE_S = 5.0


def proc_figures(pid: int) -> dict[str, float]:
    """RSS (MiB), open file descriptors and threads of one process."""
    status = Path(f"/proc/{pid}/status").read_text().splitlines()
    fields = dict(line.split(":", 1) for line in status if ":" in line)
    return {"rss_mib": int(fields["VmRSS"].split()[0]) / 1024.0,
            "fds": len(os.listdir(f"/proc/{pid}/fd")),
            "threads": int(fields["Threads"])}


def fault_cycle(rig: Rig) -> list:
    """The faults, each a (name, start, end) pair of actions."""
    return [
        ("packet loss 0.1 %",
         lambda: control(rig.camera.control_port, {"set": {"lost_ratio": 0.001}}),
         lambda: control(rig.camera.control_port, {"set": {"lost_ratio": 0.0}})),
        ("PLC away", rig.plc.kill, rig.plc.start),
        ("camera away", rig.camera.kill, rig.camera.start),
    ]


def soak(rig: Rig, faults: int, fault_every_s: float, fault_len_s: float) -> dict:
    """``faults`` faults of the cycle in turn, one every ``fault_every_s`` (the first after
    half of it), then half of it more of running: the count of faults decides the
    end, not the clock, so a slow machine runs longer, not fewer faults."""
    pid = rig.svc.proc.pid
    samples, done = [], []
    cycle = fault_cycle(rig)
    t0 = time.monotonic()
    next_fault = t0 + fault_every_s / 2
    while True:
        now = time.monotonic()
        if now >= next_fault:
            if len(done) == faults:
                break
            name, start, end = cycle[len(done) % len(cycle)]
            start()
            time.sleep(fault_len_s)
            end()
            done.append({"t_s": now - t0, "fault": name})
            next_fault = now + (fault_every_s if len(done) < faults else fault_every_s / 2)
        st = rig.status()
        p = st["pipeline"]
        samples.append({"t_s": time.monotonic() - t0, **proc_figures(pid),
                        "measured": p["measured"], "camera_dropped": p["camera_dropped"],
                        "subscriber_dropped": p["subscriber_dropped"],
                        "camera_state": st["camera"]["state"]})
        time.sleep(SAMPLE_S)
    return {"seconds": time.monotonic() - t0, "faults": done, "samples": samples}


def summary(result: dict) -> dict:
    s = result["samples"]
    q = max(1, len(s) // 4)
    second, last = s[q:2 * q] or s[:1], s[-q:]
    return {"rss_start_mib": s[0]["rss_mib"],
            "rss_second_quarter_mib": statistics.median(x["rss_mib"] for x in second),
            "rss_last_quarter_mib": statistics.median(x["rss_mib"] for x in last),
            "rss_max_mib": max(x["rss_mib"] for x in s),
            "fds_start": s[0]["fds"], "fds_end": s[-1]["fds"], "fds_max": max(x["fds"] for x in s),
            "threads_start": s[0]["threads"], "threads_end": s[-1]["threads"],
            "threads_max": max(x["threads"] for x in s),
            "measured": s[-1]["measured"] - s[0]["measured"],
            "camera_dropped": s[-1]["camera_dropped"],
            "subscriber_dropped": s[-1]["subscriber_dropped"], "faults": len(result["faults"])}


def run_and_check(tmp_path, sim_plc_factory, faults: int, fault_every_s: float,
                  out: Path | None, fault_len_s: float = 8.0) -> dict:
    rig = start_rig(tmp_path, sim_plc_factory)
    try:
        control(rig.camera.control_port, {"set": {"fps": 25.0}})
        result = soak(rig, faults, fault_every_s, fault_len_s=fault_len_s)
        until(lambda: rig.svc.get("/readyz").status_code == 200, 60,
              "measuring again after the last fault")
        end = proc_figures(rig.svc.proc.pid)
    finally:
        stop_service(rig.svc)
        rig.camera.stop()
    s = summary(result)
    s["after_recovery"] = end
    if out is not None:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps({"summary": s, **result}, indent=2))
    print(json.dumps(s, indent=2))
    assert s["faults"] == faults and s["measured"] > 0
    # Nothing leaks per fault: descriptors and threads come back to where they were.
    assert end["fds"] <= s["fds_start"] + 4, s
    assert end["threads"] <= s["threads_start"] + 2, s
    return s


def test_soak_short(tmp_path, sim_plc_factory) -> None:
    # Each fault once (12 s apart, 7 s long: past the 6 s in which Aravis calls a camera
    # lost), then recovery; ``make soak`` the hour.
    run_and_check(tmp_path, sim_plc_factory, faults=3, fault_every_s=12.0, out=None,
                  fault_len_s=7.0)


@pytest.mark.slow
def test_soak_long(tmp_path, sim_plc_factory) -> None:
    seconds = float(os.environ.get("SHAFTGAUGE_SOAK_S", "3600"))
    s = run_and_check(tmp_path, sim_plc_factory, faults=max(1, round(seconds / 120.0)),
                      fault_every_s=120.0,
                      out=Path("bench-results/soak.json"))
    # Memory levels off: the last quarter holds within 10 % (and 30 MiB) of the second.
    growth = s["rss_last_quarter_mib"] - s["rss_second_quarter_mib"]
    assert growth < max(30.0, 0.1 * s["rss_second_quarter_mib"]), s
