"""Measurements per second the whole service sustains, and the latency from a frame's arrival
(when the camera driver received it) to its measurement in the Modbus registers (inside the
service), and as a client sees it over REST and over Modbus TCP, for ``shaftgauge serve`` on
the simulated GigE camera at several frame rates.

The service's own figures come from a run with no client; then, for ``--client-seconds``,
two threads poll ``/api/v1/measurements/latest`` and the
``measurement_seq`` register every 10 ms and note when each sequence number first appears;
the frame's arrival is the record's publication time less its ``latency_ms`` (same machine,
same wall clock). Polling adds up to 10 ms (5 ms on average): the pollers are clients of the
service too, 200 requests a second between them. The simulated camera replays a
ring of pre-rendered frames (``sim_replay_frames``), so that it does not compete with the
service for the CPU; each frame rate runs with the camera's region of interest following the
stripe and with the whole sensor. The service measures in worker processes, as installed.
"CPU" is the service's user and system time over the run (its own process and its measuring
workers, not the simulators), in % of one core.

Run: ``.venv/bin/python -m tests.bench.service_throughput [--seconds S] [--fps F ...]
[--roi on off]``.
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import threading
import time
from pathlib import Path

import httpx
from pymodbus.client import ModbusTcpClient

from drivers.plc.registers import REGISTERS, RegisterType, WordOrder, from_words
from drivers.sim.control import control
from tests.bench.results import save_report
from tests.e2e.conftest import measuring_workers, start_service, stop_service

POLL_S = 0.01
SEQ = next(r for r in REGISTERS if r.name == "measurement_seq")


def poll_rest(url: str, seen: dict[int, float], stop: threading.Event) -> None:
    with httpx.Client(timeout=5) as client:
        while not stop.is_set():
            r = client.get(url + "/api/v1/measurements/latest")
            if r.status_code == 200:
                seen.setdefault(r.json()["seq"], time.time())
            time.sleep(POLL_S)


def poll_modbus(port: int, seen: dict[int, float], stop: threading.Event) -> None:
    client = ModbusTcpClient("127.0.0.1", port=port, timeout=2)
    client.connect()
    try:
        while not stop.is_set():
            rr = client.read_holding_registers(SEQ.address, count=2, device_id=1)
            if not rr.isError():
                seen.setdefault(from_words(rr.registers, RegisterType.U32, WordOrder.BIG),
                                time.time())
            time.sleep(POLL_S)
    finally:
        client.close()


def percentiles(values: list[float]) -> dict[str, float | None]:
    if not values:
        return {"median_ms": None, "p99_ms": None, "n": 0}
    v = sorted(values)
    return {"median_ms": statistics.median(v), "p99_ms": v[min(len(v) - 1, int(0.99 * len(v)))],
            "n": len(v)}


def window_latencies(svc, since: float, until: float) -> list[float]:
    """Frame -> registers latency (ms) of every measurement published between two wall-clock
    times (the service's history, page by page)."""
    out: list[float] = []
    before = None
    while True:
        params = {"since": since, "until": until, "limit": 5000}
        if before is not None:
            params["before_seq"] = before
        items = svc.get("/api/v1/measurements", params=params).json()["items"]
        if not items:
            return out
        out += [m["latency_ms"] for m in items]
        before = min(m["seq"] for m in items)


def client_latencies(svc, seen: dict[int, float]) -> list[float]:
    items = svc.get("/api/v1/measurements", params={"limit": 5000}).json()["items"]
    arrival = {m["seq"]: m["time"] - m["latency_ms"] / 1000.0 for m in items}
    return [(t - arrival[s]) * 1000.0 for s, t in seen.items() if s in arrival]


def cpu_seconds(pid: int, workers: bool = True) -> float:
    """User and system CPU time of a process so far, s, with that of its measuring worker
    processes when ``workers``."""
    total = 0.0
    for p in [pid, *(measuring_workers(pid) if workers else [])]:
        try:
            fields = Path(f"/proc/{p}/stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        total += (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    return total


def run(fps: float, seconds: float, roi: bool, client_s: float, embedded: bool = False) -> dict:
    """The service alone for ``seconds`` (its own figures), then with the two polling clients
    for ``client_s`` (the figures as a client sees them, and the service's under that load)."""
    rest_seen: dict[int, float] = {}
    modbus_seen: dict[int, float] = {}
    env = {"SHAFTGAUGE_CAMERA__AUTO_ROI": "true" if roi else "false",
           "SHAFTGAUGE_CAMERA__QUEUE_SIZE": "8"}
    with tempfile.TemporaryDirectory() as tmp:
        svc = start_service(Path(tmp), diameter=30.0, fps=fps, env=env, embedded=embedded,
                            processes=True)
        try:
            assert control(svc.control_port, {"get": "stats"})["ok"]
            time.sleep(5.0)  # warm up
            s0 = svc.get("/api/v1/status").json()
            cpu0, t0, wall0 = cpu_seconds(svc.proc.pid), time.monotonic(), time.time()
            time.sleep(seconds)
            s1 = svc.get("/api/v1/status").json()
            own = percentiles(window_latencies(svc, wall0, time.time()))
            cpu = (cpu_seconds(svc.proc.pid) - cpu0) / (time.monotonic() - t0) * 100.0
            stop = threading.Event()
            pollers = [threading.Thread(target=poll_rest, args=(svc.url, rest_seen, stop)),
                       threading.Thread(target=poll_modbus,
                                        args=(svc.modbus_port, modbus_seen, stop))]
            for t in pollers:
                t.start()
            time.sleep(client_s)
            stop.set()
            for t in pollers:
                t.join(10)
            s2 = svc.get("/api/v1/status").json()
            rest = percentiles(client_latencies(svc, rest_seen))
            modbus = percentiles(client_latencies(svc, modbus_seen))
        finally:
            stop_service(svc)
    p0, p1, p2 = s0["pipeline"], s1["pipeline"], s2["pipeline"]
    return {
        "asked_fps": fps, "roi": roi, "region": s1["camera"]["region"], "seconds": seconds,
        "service_cpu_pct": cpu,
        "measurements_per_s": (p1["measured"] - p0["measured"]) / seconds,
        "ok_per_s": (p1["ok"] - p0["ok"]) / seconds,
        "frames_in_per_s": (p1["frames_in"] - p0["frames_in"]) / seconds,
        "camera_dropped": p1["camera_dropped"] - p0["camera_dropped"],
        "latency_median_ms": own["median_ms"], "latency_p99_ms": own["p99_ms"],
        "latency_n": own["n"],
        "with_clients": {
            "seconds": client_s, "client_rest": rest, "client_modbus": modbus,
            "measurements_per_s": (p2["measured"] - p1["measured"]) / client_s,
            "camera_dropped": p2["camera_dropped"] - p1["camera_dropped"],
            "latency_p99_ms": p2["latency"]["p99_ms"]},
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=30.0)
    ap.add_argument("--fps", type=float, nargs="+", default=[25.0, 50.0, 100.0, 200.0])
    ap.add_argument("--roi", nargs="+", choices=["on", "off"], default=["on", "off"])
    ap.add_argument("--client-seconds", type=float, default=10.0)
    ap.add_argument("--embedded", action="store_true",
                    help="the embedded default as `make run` starts it (tool wear, OPC UA)")
    ap.add_argument("--json", default="bench-results/service_throughput.json")
    args = ap.parse_args()
    results = []
    for fps in args.fps:
        for roi in args.roi:
            r = run(fps, args.seconds, roi == "on", args.client_seconds, args.embedded)
            results.append(r)
            c = r["with_clients"]
            print(f"camera at {fps:4.0f} fps, region of interest {roi:>3}: "
                  f"{r['measurements_per_s']:5.1f} measurements/s ({r['ok_per_s']:.1f} ok), "
                  f"{r['camera_dropped']} frames dropped, frame -> registers median "
                  f"{r['latency_median_ms']:.1f} ms, p99 {r['latency_p99_ms']:.1f} ms, service "
                  f"CPU {r['service_cpu_pct']:.0f} % ({args.seconds:g} s; region "
                  f"{r['region']}); with two clients polling every {POLL_S * 1000:g} ms: "
                  f"{c['measurements_per_s']:.1f}/s, {c['camera_dropped']} dropped, p99 "
                  f"{c['latency_p99_ms']:.1f} ms; REST median "
                  f"{c['client_rest']['median_ms']:.0f} ms, p99 {c['client_rest']['p99_ms']:.0f}"
                  f" ms, Modbus median {c['client_modbus']['median_ms']:.0f} ms, p99 "
                  f"{c['client_modbus']['p99_ms']:.0f} ms", flush=True)
    save_report({"results": results}, "service_throughput", path=args.json)


if __name__ == "__main__":
    main()
