"""The plant side's cost and scale on one local Mosquitto (Debian's).

1. One gauge's cost of publishing: CPU time of this process (the publisher alone; the
   subscriber is ``mosquitto_sub`` in its own process) per measurement message (QoS 0) and
   per decision (QoS 1, through the SQLite outbox), 3 runs each, medians.
2. Fifty gauges' publishers in this process for ``--seconds`` (60 by default): messages
   delivered a second, lost, and decisions in order (``tests/integration/plant/fleet.py``).

Run: ``.venv/bin/python -m tests.bench.plant_publish [--seconds S] [--json FILE]``.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import resource
import statistics
import subprocess
import tempfile
import time
from pathlib import Path

from calib_store.outbox import Outbox
from service.compensation import Decision, Kind
from service.config import MqttSettings
from service.plant.mqtt import MqttPublisher
from tests.bench.results import save_report
from tests.integration.plant.conftest import Mosquitto
from tests.integration.plant.fleet import _record, run_fleet


def _broker_cpu_s(broker: Mosquitto) -> float:
    """The broker process's CPU time so far (user + system), from /proc."""
    fields = Path(f"/proc/{broker.proc.pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _cpu_s() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


async def _one_gauge(port: int, folder: Path, kind: str, n: int, rate_hz: float) -> dict:
    """CPU per message of one publisher sending ``n`` messages of ``kind`` at ``rate_hz``."""
    topic = "measurement" if kind == "measurement" else "decision"
    sink = (folder / f"sub-{kind}-{time.monotonic_ns()}.txt").open("w")
    counter = subprocess.Popen(["stdbuf", "-oL", "mosquitto_sub", "-p", str(port), "-t",
                                f"shaftgauge/+/{topic}", "-q", "1"], stdout=sink)
    await asyncio.sleep(0.3)
    pub = MqttPublisher(MqttSettings(host="127.0.0.1", port=port, gauge_id="bench",
                                     measurement_hz=rate_hz * 2, health_s=3600,
                                     decision_repeat_s=0),
                        Outbox(folder / f"{kind}-{time.monotonic_ns()}.db", 100_000), dict)
    task = asyncio.create_task(pub.run())
    while not pub.connected:
        await asyncio.sleep(0.02)
    c0, t0 = _cpu_s(), time.monotonic()
    for i in range(1, n + 1):
        if kind == "measurement":
            pub.measurement(_record(i))
        else:
            pub.decision(Decision(Kind.WRITE, "offset", float(i), offset_mm=-0.001,
                                  offset_seq=i, code="offset"))
        await asyncio.sleep(max(0.0, t0 + i / rate_hz - time.monotonic()))
    while (pub.counters["measurements"] if kind == "measurement"
           else pub.counters["decisions"]) < n and time.monotonic() < t0 + n / rate_hz + 30:
        await asyncio.sleep(0.01)
    cpu = _cpu_s() - c0
    sent = pub.counters["measurements"] if kind == "measurement" else pub.counters["decisions"]
    task.cancel()
    await asyncio.gather(task, return_exceptions=True)
    await pub.close()
    await asyncio.sleep(1.0)
    counter.terminate()
    counter.wait(30)
    sink.close()
    received = len(Path(sink.name).read_text().splitlines())
    return {"kind": kind, "fed": n, "sent": sent, "received": received,
            "cpu_us_per_message": 1e6 * cpu / max(sent, 1)}


def _paho_cost(port: int, n: int, rate_hz: float) -> dict:
    """The same measurement messages through paho-mqtt's own network thread (the other
    candidate), for the choice of library: CPU per message of this process."""
    import paho.mqtt.client as paho

    from service.plant.mqtt import measurement_payload

    client = paho.Client(paho.CallbackAPIVersion.VERSION2, client_id="bench-paho")
    client.connect("127.0.0.1", port)
    client.loop_start()
    time.sleep(0.3)
    c0, t0 = _cpu_s(), time.monotonic()
    for i in range(1, n + 1):
        client.publish("shaftgauge/paho/measurement",
                       json.dumps(measurement_payload(_record(i), "paho")).encode(), qos=0)
        time.sleep(max(0.0, t0 + i / rate_hz - time.monotonic()))
    cpu = _cpu_s() - c0
    client.loop_stop()
    client.disconnect()
    return {"cpu_us_per_message": 1e6 * cpu / n}


async def main_async(seconds: float) -> dict:
    with tempfile.TemporaryDirectory(prefix="shaftgauge-plant-") as tmp:
        folder = Path(tmp)
        broker = Mosquitto(folder / "broker").start()
        try:
            cost = {}
            for kind, n, rate in (("measurement", 5000, 500.0), ("decision", 1000, 200.0)):
                runs = [await _one_gauge(broker.port, folder, kind, n, rate) for _ in range(3)]
                cost[kind] = {"runs": runs, "median_cpu_us_per_message": statistics.median(
                    r["cpu_us_per_message"] for r in runs)}
                print(f"{kind}: {n} at {rate:g}/s, 3 runs, median "
                      f"{cost[kind]['median_cpu_us_per_message']:.0f} us CPU a message "
                      f"(sent/received: {[(r['sent'], r['received']) for r in runs]})")
            paho_runs = [_paho_cost(broker.port, 5000, 500.0) for _ in range(3)]
            cost["measurement_paho"] = {"runs": paho_runs, "median_cpu_us_per_message":
                                        statistics.median(r["cpu_us_per_message"]
                                                          for r in paho_runs)}
            print(f"measurement through paho-mqtt's thread: median "
                  f"{cost['measurement_paho']['median_cpu_us_per_message']:.0f} us CPU a "
                  "message")
            fleets = {}
            for gauges, secs in ((50, seconds), (100, seconds / 3)):
                b0 = _broker_cpu_s(broker)
                fleet = await run_fleet(broker.port, folder, gauges=gauges, seconds=secs)
                broker_cpu = _broker_cpu_s(broker) - b0
                fleets[f"{gauges}_gauges"] = {**fleet.as_dict(), "broker_cpu_s": broker_cpu}
                print(f"{gauges} gauges x {secs:g} s: {fleet.delivered_per_s:.1f} messages/s "
                      f"delivered, {fleet.measurements_lost} measurements and "
                      f"{fleet.decisions_lost} decisions lost, {fleet.decisions_out_of_order} "
                      f"out of order; CPU {fleet.cpu_s:.1f} s (publishers and subscriber), "
                      f"Mosquitto {broker_cpu:.1f} s ({100 * broker_cpu / (secs + 3):.1f} % "
                      "of a core)")
        finally:
            broker.stop()
    return {"cost": cost, "fleets": fleets}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--json")
    args = ap.parse_args()
    t0 = time.monotonic()
    report = asyncio.run(main_async(args.seconds))
    report["seconds"] = time.monotonic() - t0
    save_report(report, "plant_publish", path=args.json)


if __name__ == "__main__":
    main()
