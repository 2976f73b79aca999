"""Measurements per second the whole service sustains, and the latency from a frame's arrival
(when the camera driver received it) to its measurement in the Modbus registers (inside the
service), and as a client sees it over REST and over Modbus TCP, for ``shaftgauge serve`` on
the simulated GigE camera at several frame rates.

The client-side figures: two threads poll ``/api/v1/measurements/latest`` and the
``measurement_seq`` register every 5 ms and note when each sequence number first appears;
the frame's arrival is the record's publication time less its ``latency_ms`` (same machine,
same wall clock). Polling adds up to 5 ms (2.5 ms on average).

Run: ``.venv/bin/python -m tests.bench.service_throughput [--seconds S] [--fps F ...]``.
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import threading
import time
from pathlib import Path

import httpx
from pymodbus.client import ModbusTcpClient

from drivers.plc.registers import REGISTERS, RegisterType, WordOrder, from_words
from drivers.sim.control import control
from tests.e2e.conftest import start_service, stop_service

POLL_S = 0.005
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


def client_latencies(svc, seen: dict[int, float]) -> list[float]:
    items = svc.get("/api/v1/measurements", params={"limit": 5000}).json()["items"]
    arrival = {m["seq"]: m["time"] - m["latency_ms"] / 1000.0 for m in items}
    return [(t - arrival[s]) * 1000.0 for s, t in seen.items() if s in arrival]


def run(fps: float, seconds: float) -> dict:
    rest_seen: dict[int, float] = {}
    modbus_seen: dict[int, float] = {}
    with tempfile.TemporaryDirectory() as tmp:
        svc = start_service(Path(tmp), diameter=30.0, fps=fps)
        try:
            assert control(svc.control_port, {"get": "stats"})["ok"]
            time.sleep(5.0)  # warm up
            s0 = svc.get("/api/v1/status").json()
            stop = threading.Event()
            pollers = [threading.Thread(target=poll_rest, args=(svc.url, rest_seen, stop)),
                       threading.Thread(target=poll_modbus,
                                        args=(svc.modbus_port, modbus_seen, stop))]
            for t in pollers:
                t.start()
            time.sleep(seconds)
            stop.set()
            for t in pollers:
                t.join(10)
            s1 = svc.get("/api/v1/status").json()
            rest = percentiles(client_latencies(svc, rest_seen))
            modbus = percentiles(client_latencies(svc, modbus_seen))
        finally:
            stop_service(svc)
    p0, p1 = s0["pipeline"], s1["pipeline"]
    return {
        "client_rest": rest, "client_modbus": modbus,
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
              f"frame -> registers median {r['latency_median_ms']:.0f} ms, p99 "
              f"{r['latency_p99_ms']:.0f} ms; as a client sees it: REST median "
              f"{r['client_rest']['median_ms']:.0f} ms, p99 {r['client_rest']['p99_ms']:.0f} ms,"
              f" Modbus median {r['client_modbus']['median_ms']:.0f} ms, p99 "
              f"{r['client_modbus']['p99_ms']:.0f} ms ({args.seconds:g} s)")
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json).write_text(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()
