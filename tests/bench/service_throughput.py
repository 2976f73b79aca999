"""Measurements per second the whole service sustains, and the latency from a frame's arrival
(``time.monotonic_ns()`` when the camera driver received it) to the Modbus register update,
for ``shaftgauge serve`` on the simulated GigE camera at several frame rates.

Run: ``.venv/bin/python -m tests.bench.service_throughput [--seconds S] [--fps F ...]``.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

from drivers.sim.control import control
from tests.e2e.conftest import start_service, stop_service


def run(fps: float, seconds: float) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        svc = start_service(Path(tmp), diameter=30.0, fps=fps)
        try:
            assert control(svc.control_port, {"get": "stats"})["ok"]
            time.sleep(5.0)  # warm up
            s0 = svc.get("/api/v1/status").json()
            time.sleep(seconds)
            s1 = svc.get("/api/v1/status").json()
        finally:
            stop_service(svc)
    p0, p1 = s0["pipeline"], s1["pipeline"]
    return {
        "asked_fps": fps,
        "measurements_per_s": (p1["measured"] - p0["measured"]) / seconds,
        "ok_per_s": (p1["ok"] - p0["ok"]) / seconds,
        "frames_in_per_s": (p1["frames_in"] - p0["frames_in"]) / seconds,
        "camera_dropped": p1["camera_dropped"] - p0["camera_dropped"],
        "latency_median_ms": p1["latency"]["median_ms"],
        "latency_p99_ms": p1["latency"]["p99_ms"],
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=30.0)
    ap.add_argument("--fps", type=float, nargs="+", default=[10.0, 25.0, 50.0])
    ap.add_argument("--json", default="bench-results/service_throughput.json")
    args = ap.parse_args()
    results = []
    for fps in args.fps:
        r = run(fps, args.seconds)
        results.append(r)
        print(f"camera at {fps:4.0f} fps: {r['measurements_per_s']:5.1f} measurements/s "
              f"({r['ok_per_s']:.1f} ok), {r['camera_dropped']} frames dropped, latency "
              f"frame -> Modbus median {r['latency_median_ms']:.0f} ms, p99 "
              f"{r['latency_p99_ms']:.0f} ms ({args.seconds:g} s)")
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json).write_text(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()
