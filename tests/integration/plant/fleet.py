"""A fleet of simulated gauges' MQTT publishers in one process against one broker, and a plant
subscriber counting what arrives: the scale test's and the plant bench's engine."""

from __future__ import annotations

import asyncio
import itertools
import json
import resource
import time
from dataclasses import dataclass
from pathlib import Path

import aiomqtt

from calib_store.outbox import Outbox
from service.compensation import Decision, Kind
from service.config import MqttSettings
from service.measurement_record import MeasurementRecord
from service.plant.mqtt import MqttPublisher


@dataclass
class FleetResult:
    """What a fleet run sent and what the subscriber got."""

    gauges: int
    seconds: float
    measurements_sent: int
    measurements_received: int
    decisions_sent: int
    decisions_received: int
    decisions_out_of_order: int
    cpu_s: float  # this process: publishers, their feeding, and the subscriber
    # rounds fed (one measurement to every gauge), and of those the ones the next round
    # followed within the publisher's own minimum interval: a stall of this process (the
    # machine busy elsewhere) fed those in a burst, and each gauge keeps only its latest
    rounds_fed: int = 0
    rounds_superseded: int = 0
    longest_stall_s: float = 0.0
    latest_received: int = 0
    """Gauges whose last measurement received is the last round fed (each keeps only its
    latest and sends it when its rate allows: the newest always goes out)."""
    measurements_out_of_order: int = 0

    @property
    def delivered_per_s(self) -> float:
        return (self.measurements_received + self.decisions_received) / self.seconds

    @property
    def measurements_lost(self) -> int:
        return self.measurements_sent - self.measurements_received

    @property
    def decisions_lost(self) -> int:
        return self.decisions_sent - self.decisions_received

    def as_dict(self) -> dict:
        return {**self.__dict__, "delivered_per_s": round(self.delivered_per_s, 1),
                "measurements_lost": self.measurements_lost,
                "decisions_lost": self.decisions_lost}


def _record(seq: int) -> MeasurementRecord:
    return MeasurementRecord(
        seq=seq, time=time.time(), frame_id=seq, method="axis", status="ok",
        diameter_mm=30.0 + 1e-4 * (seq % 7), raw_diameter_mm=30.0, uncertainty_mm=0.002,
        diameter_20c_mm=None, fused_diameter_mm=30.0, fused_uncertainty_mm=0.0005,
        deviation_mm=0.0, in_tolerance=True, arc_deg=120.0, n_points=400,
        rms_residual_mm=0.001, latency_ms=3.0, reason="", note="", calibration_id=1)


async def _subscriber(port: int, got: dict[str, list[tuple[str, int]]],
                      ready: asyncio.Event) -> None:
    async with aiomqtt.Client("127.0.0.1", port, identifier="fleet-historian",
                              max_queued_incoming_messages=0) as client:
        await client.subscribe("shaftgauge/+/measurement", qos=0)
        await client.subscribe("shaftgauge/+/decision", qos=1)
        ready.set()
        async for m in client.messages:
            leaf = str(m.topic).rsplit("/", 1)[1]
            if leaf in got:
                body = json.loads(m.payload)
                got[leaf].append((body["gauge_id"], body.get("seq", body.get("decision_seq"))))


async def run_fleet(port: int, folder: Path, gauges: int = 50, seconds: float = 60.0,
                    measurement_hz: float = 10.0, decision_every_s: float = 5.0
                    ) -> FleetResult:
    """``gauges`` publishers, each fed a measurement every ``1/measurement_hz`` s (all sent,
    QoS 0) and a decision every ``decision_every_s`` (QoS 1, through its outbox), for
    ``seconds``; then 3 s for the last messages to arrive."""
    got: dict[str, list[tuple[str, int]]] = {"measurement": [], "decision": []}
    ready = asyncio.Event()
    sub = asyncio.create_task(_subscriber(port, got, ready))
    await asyncio.wait_for(ready.wait(), 10)
    pubs = [MqttPublisher(MqttSettings(host="127.0.0.1", port=port, gauge_id=f"g{i:03d}",
                                       measurement_hz=2 * measurement_hz, health_s=3600),
                          Outbox(folder / f"outbox-{i}.db", 10_000), dict)
            for i in range(gauges)]
    tasks = [asyncio.create_task(p.run()) for p in pubs]
    deadline = time.monotonic() + 10
    while not all(p.connected for p in pubs) and time.monotonic() < deadline:
        await asyncio.sleep(0.05)
    cpu0 = resource.getrusage(resource.RUSAGE_SELF)
    t0 = time.monotonic()
    seq, decisions, next_decision = 0, 0, t0 + decision_every_s
    period = 1.0 / measurement_hz
    fed_at: list[float] = []
    while (now := time.monotonic()) < t0 + seconds:
        seq += 1
        fed_at.append(now)
        for p in pubs:
            p.measurement(_record(seq))
        if now >= next_decision:
            decisions += 1
            for p in pubs:
                p.decision(Decision(Kind.PROPOSED, "proposed", now, offset_mm=-0.001,
                                    code=f"d{decisions}", shadow=True))
            next_decision += decision_every_s
        await asyncio.sleep(max(0.0, t0 + seq * period - time.monotonic()))
    await asyncio.sleep(3.0)
    cpu1 = resource.getrusage(resource.RUSAGE_SELF)
    for t in tasks:
        t.cancel()
    await asyncio.gather(*tasks, return_exceptions=True)
    for p in pubs:
        await p.close()
    sub.cancel()
    await asyncio.gather(sub, return_exceptions=True)
    sent_m = sum(p.counters["measurements"] for p in pubs)
    gaps = [b - a for a, b in itertools.pairwise(fed_at)]
    min_interval_s = 1.0 / (2 * measurement_hz)  # the publishers are given twice the rate
    order_breaks = measurement_breaks = latest = 0
    for i in range(gauges):
        ds = [s for g, s in got["decision"] if g == f"g{i:03d}"]
        order_breaks += sum(1 for a, b in itertools.pairwise(ds) if b != a + 1)
        ms = [s for g, s in got["measurement"] if g == f"g{i:03d}"]
        measurement_breaks += sum(1 for a, b in itertools.pairwise(ms) if b <= a)
        latest += bool(ms) and ms[-1] == seq
    return FleetResult(
        gauges=gauges, seconds=seconds, measurements_sent=sent_m,
        measurements_received=len(got["measurement"]), decisions_sent=decisions * gauges,
        decisions_received=len(got["decision"]), decisions_out_of_order=order_breaks,
        cpu_s=(cpu1.ru_utime + cpu1.ru_stime) - (cpu0.ru_utime + cpu0.ru_stime),
        rounds_fed=seq, rounds_superseded=sum(g < min_interval_s for g in gaps),
        longest_stall_s=max((g - period for g in gaps), default=0.0),
        latest_received=latest, measurements_out_of_order=measurement_breaks)
