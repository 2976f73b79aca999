"""The speed guard: a quick core bench and a quick service bench whose ratios ``make test``
holds against the last committed ones (``bench-results/guard.json``, written by ``make
bench``), so that a change that costs speed fails in the submission that makes it.

Ratios, not times: this machine's speed swings by 2x within hours, but two things timed in
the same few seconds swing together.
- Core: the fair plain Steger's time (``plain_steger``) over the core's tracked median
  frame, on the default rig and on the thick-sheet rig (``WIDE_RIG``); a frame checked for a
  reflection over a tracked one. Each the median of ``ROUNDS`` interleaved rounds.
- Service: ``shaftgauge serve`` at 100 frames/s on the simulated camera, measured in worker
  processes as installed: measurements over the frames the camera delivered (those it
  dropped in its queue among them), frames dropped a second, and the fair plain Steger's
  time measured just before over the service's CPU (its own and its workers') per
  measurement: the whole service's cost in the core's yardstick, so that a slower core and a
  heavier service both show, and a faster core does not read as a heavier service (the
  core's frame time over the service's CPU, used before, fell when the core got faster).

Run: ``.venv/bin/python -m tests.bench.guard [--runs N] [--write]`` (``--write``: the new
baseline, with the machine, the commit and the date). ``make bench`` writes the lowest of
three runs for each ratio: three runs in a row gave the plain Steger over the core 23.0,
22.6 and 19.4, and on another day's slow phase 15.7; a baseline from one fast run would fail
such a phase at 0.7 of it.
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import cv2

from service.measure.diameter import MeasureParams
from service.measure.geometry import geometry_of
from service.measure.result import Method
from tests.bench.core_throughput import WIDE_RIG, run_core, sequences
from tests.bench.plain_steger import plain_steger
from tests.bench.results import ROOT, save_report

BASELINE = ROOT / "bench-results" / "guard.json"
ROUNDS = 5
SERVICE_FPS = 100.0
SERVICE_S = 6.0


def quick_core(rounds: int = ROUNDS) -> dict[str, float]:
    """The core's ratios (larger is faster), each the median over ``rounds`` rounds."""
    cv2.setNumThreads(1)
    params = MeasureParams(reflection_check=False)
    data, rig = sequences(1, 12, 21)
    wide, wide_rig = sequences(1, 12, 21, **WIDE_RIG)
    g, wg = geometry_of(rig.calibration), geometry_of(wide_rig.calibration)
    plain_frames = [image for image, _ in data[0][:: 4]]
    checked = replace(params, reflection_check=True)
    for seq, geo in ((data, g), (wide, wg)):  # warm caches and compiled code
        run_core(seq, geo, Method.AXIS, params)
    plain_steger(plain_frames[0], params.stripe)
    out: dict[str, list[float]] = {"plain_over_core": [], "plain_over_wide": [],
                                   "checked_over_tracked": [], "core_ms": [], "plain_ms": []}
    for _ in range(rounds):
        t = time.perf_counter()
        for image in plain_frames:
            plain_steger(image, params.stripe)
        plain_ms = (time.perf_counter() - t) / len(plain_frames) * 1000.0
        core = statistics.median(run_core(data, g, Method.AXIS, params)[3])
        wide_ms = statistics.median(run_core(wide, wg, Method.AXIS, params)[3])
        check = statistics.median(run_core(data, g, Method.AXIS, checked)[3])
        out["plain_over_core"].append(plain_ms / core)
        out["plain_over_wide"].append(plain_ms / wide_ms)
        out["checked_over_tracked"].append(core / check)
        out["core_ms"].append(core)
        out["plain_ms"].append(plain_ms)
    return {k: float(statistics.median(v)) for k, v in out.items()}


def quick_service(plain_ms: float, seconds: float = SERVICE_S) -> dict[str, float]:
    """The service's ratios at ``SERVICE_FPS`` (larger is better)."""
    from tests.bench.service_throughput import cpu_seconds
    from tests.e2e.conftest import start_service, stop_service, wait_ready

    env = {"SHAFTGAUGE_CAMERA__AUTO_ROI": "true", "SHAFTGAUGE_CAMERA__QUEUE_SIZE": "8"}
    with tempfile.TemporaryDirectory() as tmp:
        svc = start_service(Path(tmp), fps=SERVICE_FPS, env=env, processes=True)
        try:
            wait_ready(svc)
            time.sleep(3.0)  # the workers spawned and warm
            s0 = svc.get("/api/v1/status").json()["pipeline"]
            c0, t0 = cpu_seconds(svc.proc.pid), time.monotonic()
            time.sleep(seconds)
            dt = time.monotonic() - t0
            cpu = cpu_seconds(svc.proc.pid) - c0
            s1 = svc.get("/api/v1/status").json()["pipeline"]
        finally:
            stop_service(svc)
    measured = s1["measured"] - s0["measured"]
    dropped = s1["camera_dropped"] - s0["camera_dropped"]
    delivered = s1["frames_in"] - s0["frames_in"] + dropped
    return {"measured_over_frames": measured / max(delivered, 1),
            "frames_per_s": delivered / dt,
            "dropped_per_s": dropped / dt,
            # The yardstick's time over the service's CPU per measurement.
            "plain_over_service_cpu": plain_ms / (cpu / max(measured, 1) * 1000.0)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--write", action="store_true", help="write the new baseline")
    ap.add_argument("--rounds", type=int, default=ROUNDS)
    ap.add_argument("--runs", type=int, default=1,
                    help="whole runs; each ratio's lowest is reported (the baseline: the "
                         "machine's slower moments are not a regression)")
    args = ap.parse_args()
    runs = []
    for _ in range(args.runs):
        core = quick_core(args.rounds)
        runs.append({"core": core, "service": quick_service(core["plain_ms"])})
    report = {part: {k: min(r[part][k] for r in runs) for k in runs[0][part]}
              for part in ("core", "service")}
    report["runs"] = args.runs
    print(json.dumps(report, indent=2))
    if args.write:
        save_report(report, "guard", path=str(BASELINE))


if __name__ == "__main__":
    main()
