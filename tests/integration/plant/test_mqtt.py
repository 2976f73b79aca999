"""The MQTT publisher against a real Mosquitto: topics and payloads, decisions stored and
forwarded across a broker outage (none lost, none doubled, in order), TLS with a test CA, a
wrong password refused."""

from __future__ import annotations

import asyncio
import json
import ssl
from dataclasses import dataclass, field
from pathlib import Path

import aiomqtt
import pytest

from calib_store.outbox import Outbox
from service.compensation import Decision, Kind
from service.config import MqttSettings
from service.measurement_record import MeasurementRecord
from service.plant.mqtt import MqttPublisher
from tests.integration.plant.conftest import Mosquitto, make_test_ca, wait_until


@dataclass
class Collector:
    """A plant subscriber with a persistent session (QoS 1): it gets what was published
    while it was away, across a broker restart (Mosquitto keeps the session on disk)."""

    port: int
    topic: str
    tls_ca: Path | None = None
    auth: tuple[str, str] | None = None
    messages: list[tuple[str, bytes, bool]] = field(default_factory=list)
    connected: bool = False

    async def run(self) -> None:
        tls = None if self.tls_ca is None else aiomqtt.TLSParameters(
            ca_certs=str(self.tls_ca), cert_reqs=ssl.CERT_REQUIRED)
        while True:
            try:
                async with aiomqtt.Client(
                        "127.0.0.1", self.port, identifier="plant-historian",
                        clean_session=False, tls_params=tls,
                        username=self.auth[0] if self.auth else None,
                        password=self.auth[1] if self.auth else None) as client:
                    await client.subscribe(self.topic, qos=1)
                    self.connected = True
                    async for m in client.messages:
                        self.messages.append((str(m.topic), bytes(m.payload), m.retain))
            except aiomqtt.MqttError:
                self.connected = False
                await asyncio.sleep(0.2)

    def on(self, leaf: str) -> list[bytes]:
        return [p for t, p, _ in self.messages if t.endswith("/" + leaf)]


def record(seq: int, diameter_mm: float = 30.0) -> MeasurementRecord:
    return MeasurementRecord(
        seq=seq, time=1.7e9 + seq, frame_id=seq, method="axis", status="ok",
        diameter_mm=diameter_mm, raw_diameter_mm=diameter_mm, uncertainty_mm=0.002,
        diameter_20c_mm=None, fused_diameter_mm=diameter_mm, fused_uncertainty_mm=0.0005,
        deviation_mm=0.001, in_tolerance=True, arc_deg=120.0, n_points=400,
        rms_residual_mm=0.001, latency_ms=3.0, reason="", note="", calibration_id=1)


def write(i: int) -> Decision:
    return Decision(Kind.WRITE, f"offset {i}", float(i), measurement_seq=i,
                    offset_mm=-0.001, offset_seq=i, code="offset")


async def running(pub: MqttPublisher) -> asyncio.Task:
    task = asyncio.create_task(pub.run())
    assert await wait_until(lambda: pub.connected or bool(pub.problem), 10)
    return task


async def listening(sub: Collector) -> asyncio.Task:
    """The subscriber running and subscribed."""
    task = asyncio.create_task(sub.run())
    assert await wait_until(lambda: sub.connected)
    return task


async def stopped(pub: MqttPublisher, task: asyncio.Task) -> None:
    task.cancel()
    await asyncio.gather(task, return_exceptions=True)
    await pub.close()


async def test_measurements_decisions_state_and_health_reach_a_subscriber(
        mosquitto: Mosquitto, tmp_path: Path) -> None:
    sub = Collector(mosquitto.port, "shaftgauge/#")
    sub_task = await listening(sub)
    settings = MqttSettings(host="127.0.0.1", port=mosquitto.port, gauge_id="lathe-7",
                            measurement_hz=5, health_s=0.5, decision_repeat_s=60)
    pub = MqttPublisher(settings, Outbox(tmp_path / "outbox.db", 100), lambda: {"ok": 1})
    task = await running(pub)
    assert pub.connected, pub.problem
    for i in range(1, 31):  # 30 records in 1.5 s at 5 Hz: about 8 sent, the latest among them
        pub.measurement(record(i, 30.0 + i * 1e-4))
        await asyncio.sleep(0.05)
    pub.decision(write(1))
    for _ in range(5):  # identical quiet decisions: the first is sent, the rest counted
        pub.decision(Decision(Kind.HELD, "held: deadband", 0.0, code="deadband"))
    pub.decision(write(2))
    for k in (41, 42):  # one message a part
        pub.part({"serial": f"SH-4711-{k}", "time": 1.8e9 + k, "part_number": "SH-4711",
                  "verdict": "ok", "features": [{"feature": 1, "diameter_mm": 30.001}]})
    assert await wait_until(lambda: len(sub.on("decision")) >= 3 and sub.on("health")
                            and len(sub.on("part")) == 2
                            and 30 in [json.loads(p)["seq"] for p in sub.on("measurement")])
    ms = [json.loads(p) for p in sub.on("measurement")]
    assert 4 <= len(ms) <= 12, len(ms)  # at most 5 a second
    assert ms[-1]["diameter_mm"] == pytest.approx(30.003)
    assert {"seq", "time", "status", "diameter_mm", "uncertainty_mm", "fused_diameter_mm",
            "deviation_mm", "in_tolerance", "calibration_id"} <= set(ms[-1])
    parts = [json.loads(p) for p in sub.on("part")]
    assert [p["serial"] for p in parts] == ["SH-4711-41", "SH-4711-42"]
    assert parts[0]["gauge_id"] == "lathe-7" and parts[0]["features"][0]["feature"] == 1
    ds = [json.loads(p) for p in sub.on("decision")]
    assert [(d["kind"], d["decision_seq"]) for d in ds] == [
        ("write", 1), ("held", 2), ("write", 3)]
    assert ds[2]["repeats"] == 0 and pub.counters["decisions_skipped"] == 4
    assert sub.on("state")[0] == b"online"
    assert json.loads(sub.on("health")[0])["gauge_id"] == "lathe-7"
    await stopped(pub, task)
    assert await wait_until(lambda: sub.on("state")[-1:] == [b"offline"])
    sub_task.cancel()


async def test_decisions_wait_for_a_broker_that_is_away_and_arrive_once_in_order(
        mosquitto: Mosquitto, tmp_path: Path) -> None:
    sub = Collector(mosquitto.port, "shaftgauge/+/decision")
    sub_task = await listening(sub)
    settings = MqttSettings(host="127.0.0.1", port=mosquitto.port, gauge_id="g1",
                            reconnect_s=0.3)
    pub = MqttPublisher(settings, Outbox(tmp_path / "outbox.db", 10_000), dict)
    task = await running(pub)
    n, queued_max = 0, 0
    for phase_s, broker_up in ((1.0, True), (2.0, False), (1.5, True)):
        if not broker_up:
            mosquitto.stop()
        elif mosquitto.proc is None:
            mosquitto.start()
        loop_end = asyncio.get_running_loop().time() + phase_s
        while asyncio.get_running_loop().time() < loop_end:
            n += 1
            pub.decision(write(n))
            await asyncio.sleep(0.02)
            queued_max = max(queued_max, len(pub.outbox))
    assert await wait_until(lambda: len(sub.on("decision")) >= n, 20), (
        len(sub.on("decision")), n, pub.status())
    seqs = [json.loads(p)["decision_seq"] for p in sub.on("decision")]
    # QoS 1 is "at least once" (docs/mqtt.md): the decision in flight when the broker went
    # may come again, its acknowledgement lost with the connection. A subscriber keeping the
    # highest decision_seq gets every one, once, in order; the gauge sends one at a time, so
    # no more than one again per connection lost.
    kept = [q for i, q in enumerate(seqs) if q > max(seqs[:i], default=0)]
    assert kept == list(range(1, n + 1))  # every one, in order
    again = len(seqs) - len(kept)
    assert all(q == max(seqs[:i]) for i, q in enumerate(seqs) if i and q <= max(seqs[:i]))
    assert queued_max > 20  # they did wait for the broker
    # The last ones leave the outbox when the broker's acknowledgement is handled, which may
    # come just after the subscriber has them.
    assert await wait_until(lambda: len(pub.outbox) == 0, 5), len(pub.outbox)
    assert pub.counters["connects"] >= 2
    assert again <= pub.counters["connects"] - 1, (again, pub.counters)
    print(f"\nbroker outage: {n} decisions, {queued_max} queued at most, all delivered in "
          f"order ({again} sent again)")
    await stopped(pub, task)
    sub_task.cancel()


async def test_the_outbox_is_bounded_and_says_so(tmp_path: Path) -> None:
    settings = MqttSettings(host="127.0.0.1", port=1, outbox_max=10, reconnect_s=60)
    pub = MqttPublisher(settings, Outbox(tmp_path / "outbox.db", 10), dict)
    task = await running(pub)  # nothing listens on port 1: never connected
    for i in range(1, 26):
        pub.decision(write(i))
    await pub.flush()
    assert len(pub.outbox) == 10 and pub.outbox.dropped == 15
    codes = dict(pub.problems())
    assert "mqtt_unreachable" in codes and "127.0.0.1:1" in codes["mqtt_unreachable"]
    assert "15 decisions dropped" in codes["mqtt_decisions_dropped"]
    kept = [json.loads(m.payload)["decision_seq"] for m in pub.outbox.peek(100)]
    assert kept == list(range(16, 26))  # the newest kept, the oldest dropped
    await stopped(pub, task)
    again = Outbox(tmp_path / "outbox.db", 10)  # a restart keeps them and the count
    assert len(again) == 10 and again.dropped == 15
    again.close()


async def test_tls_with_a_test_ca_and_a_wrong_password_refused(tmp_path: Path) -> None:
    ca = make_test_ca(tmp_path / "ca")
    broker = Mosquitto(tmp_path / "broker", users={"gauge": "right", "historian": "h"},
                       tls=ca).start()
    try:
        sub = Collector(broker.port, "shaftgauge/+/decision", tls_ca=ca.ca,
                        auth=("historian", "h"))
        sub_task = await listening(sub)
        good = MqttPublisher(MqttSettings(host="127.0.0.1", port=broker.port, gauge_id="t",
                                          username="gauge", password="right", tls_ca=ca.ca),
                             Outbox(tmp_path / "a.db", 100), dict)
        task = await running(good)
        assert good.connected, good.problem
        good.decision(write(1))
        assert await wait_until(lambda: len(sub.on("decision")) == 1)
        await stopped(good, task)

        bad = MqttPublisher(MqttSettings(host="127.0.0.1", port=broker.port, gauge_id="t",
                                         username="gauge", password="wrong", tls_ca=ca.ca),
                            Outbox(tmp_path / "b.db", 100), dict)
        task = await running(bad)
        bad.decision(write(2))
        await asyncio.sleep(0.5)
        assert not bad.connected
        assert "not authori" in bad.problem.lower(), bad.problem
        assert dict(bad.problems())["mqtt_unreachable"].endswith("(1 decisions kept for it)")
        await stopped(bad, task)

        no_ca = MqttPublisher(MqttSettings(host="127.0.0.1", port=broker.port, gauge_id="t",
                                           username="gauge", password="right"),
                              Outbox(tmp_path / "c.db", 100), dict)
        task = await running(no_ca)  # plain MQTT to a TLS listener: refused, reported
        await asyncio.sleep(0.5)
        assert not no_ca.connected and "TLS on one side only" in no_ca.problem, no_ca.problem
        await stopped(no_ca, task)
        assert len(sub.on("decision")) == 1
        sub_task.cancel()
    finally:
        broker.stop()


async def test_a_restarted_gauge_sends_what_waited_and_numbers_on(
        mosquitto: Mosquitto, tmp_path: Path) -> None:
    away = MqttSettings(host="127.0.0.1", port=1, gauge_id="r", reconnect_s=60)
    pub = MqttPublisher(away, Outbox(tmp_path / "outbox.db", 100), dict)
    task = await running(pub)  # the broker is not reachable: three decisions wait
    for i in (1, 2, 3):
        pub.decision(write(i))
    await stopped(pub, task)  # the gauge stops (or is restarted) meanwhile

    sub = Collector(mosquitto.port, "shaftgauge/r/decision")
    sub_task = await listening(sub)
    back = MqttSettings(host="127.0.0.1", port=mosquitto.port, gauge_id="r")
    pub = MqttPublisher(back, Outbox(tmp_path / "outbox.db", 100), dict)
    task = await running(pub)
    pub.decision(write(4))
    assert await wait_until(lambda: len(sub.on("decision")) == 4)
    assert [json.loads(p)["decision_seq"] for p in sub.on("decision")] == [1, 2, 3, 4]
    await stopped(pub, task)
    # an empty outbox after a restart still numbers on (a subscriber keeps the highest seen)
    pub = MqttPublisher(back, Outbox(tmp_path / "outbox.db", 100), dict)
    task = await running(pub)
    pub.decision(write(5))
    assert await wait_until(lambda: len(sub.on("decision")) == 5)
    assert json.loads(sub.on("decision")[-1])["decision_seq"] == 5
    await stopped(pub, task)
    sub_task.cancel()
