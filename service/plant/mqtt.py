"""The gauge on the plant's MQTT broker (aiomqtt): measurements, decisions, state and health.

Topics under ``<prefix>`` (``shaftgauge/<gauge id>`` unless set; ``docs/mqtt.md``):

- ``measurement``: the latest measurement as JSON, at most ``measurement_hz`` a second (the
  frames between are in its fused value), QoS ``qos_measurement`` (0: a newer one follows);
- ``decision``: the compensation decisions, QoS ``qos_decision`` (at least 1), **stored and
  forwarded**: each is put in the gauge's SQLite outbox first and taken out only when the
  broker has acknowledged it, so a broker that is away for an hour gets every decision, in
  order, when it returns (bounded by ``outbox_max``: past it the oldest are dropped, counted,
  and a problem reported). QoS 1 is "at least once": a decision whose acknowledgement was
  lost with the connection is sent again, and its ``decision_seq`` tells a subscriber so;
- ``state``: ``online`` (retained) while connected, ``offline`` (retained) on a clean stop
  and, as the broker's last will, when the gauge vanishes;
- ``health``: the gauge's health every ``health_s``.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import json
import logging
import socket
import ssl
import time
from collections.abc import Callable
from typing import Any

import aiomqtt

from calib_store.outbox import Outbox
from service.compensation import QUIET_KINDS, Decision
from service.config import MqttSettings
from service.measurement_record import MeasurementRecord, finite_or_none

log = logging.getLogger("shaftgauge.mqtt")

PUBLISH_TIMEOUT_S = 10.0
"""How long a QoS 1 publication may wait for its acknowledgement before the connection is
taken as lost (the decision stays in the outbox)."""

CONNECT_TIMEOUT_S = 4.0
"""How long the broker may take to accept a connection (CONNACK). aiomqtt does not see a
connection closed before it: plain MQTT to a TLS listener, reset by the broker, waited for
the publication timeout before it was reported."""


def gauge_identity(settings: MqttSettings) -> tuple[str, str, str]:
    """The gauge id, topic prefix and client id the settings give (host name by default)."""
    gauge_id = settings.gauge_id or socket.gethostname()
    prefix = (settings.topic_prefix or f"shaftgauge/{gauge_id}").rstrip("/")
    return gauge_id, prefix, settings.client_id or f"shaftgauge-{gauge_id}"


MEASUREMENT_FIELDS = ("seq", "time", "status", "diameter_mm", "uncertainty_mm",
                      "fused_diameter_mm", "fused_uncertainty_mm", "deviation_mm",
                      "in_tolerance", "calibration_id", "reason", "spindle_deg", "about_runout",
                      "feature")


def measurement_payload(record: MeasurementRecord, gauge_id: str) -> dict[str, Any]:
    """The ``measurement`` topic's JSON: ``MEASUREMENT_FIELDS`` of the record's API form
    (lengths in mm, ``time`` Unix seconds, None for "none")."""
    d = record.as_dict()
    return {"gauge_id": gauge_id, **{k: d[k] for k in MEASUREMENT_FIELDS}}


def decision_payload(d: Decision, gauge_id: str, decision_seq: int, wall_time: float,
                     repeats: int) -> dict[str, Any]:
    """The ``decision`` topic's JSON: the decision's fields (as in the decision log), its
    ``decision_seq`` (one more than the gauge's previous decision sent), wall-clock ``time``
    and ``repeats`` (identical quiet decisions since the previous one sent)."""
    return {"gauge_id": gauge_id, "decision_seq": decision_seq, "time": wall_time,
            "repeats": repeats, **{k: finite_or_none(v) if isinstance(v, float) else v
                                   for k, v in d.as_dict().items()}}


class RepeatFilter:
    """Which decisions go out: every significant one; a quiet one (held, refused, proposed)
    that repeats the previous one's kind and code at most every ``repeat_s`` seconds.

    Parameters
    ----------
    repeat_s : float
        Seconds between two identical quiet decisions sent (0: every one).
    """

    def __init__(self, repeat_s: float) -> None:
        self.repeat_s = repeat_s
        self._last: tuple[str, str] | None = None
        self._last_sent_s = -float("inf")
        self._repeats = 0

    def admit(self, d: Decision, now_s: float) -> int | None:
        """None to skip ``d``; else the number of identical decisions skipped before it."""
        key = (d.kind.value, d.code)
        if d.kind in QUIET_KINDS and key == self._last \
                and now_s - self._last_sent_s < self.repeat_s:
            self._repeats += 1
            return None
        repeats = self._repeats if key == self._last else 0
        self._last, self._last_sent_s, self._repeats = key, now_s, 0
        return repeats


class MqttPublisher:
    """Publishes the gauge on an MQTT broker and keeps decisions for it while it is away.

    Parameters
    ----------
    settings : MqttSettings
        Broker, identity, TLS, QoS and rates.
    outbox : Outbox
        Where decisions wait for the broker (used from one thread of this publisher's own).
    health : callable
        Returns the gauge's health (JSON-ready) for the ``health`` topic.
    outbox_problem : str
        Why the outbox is not the one asked for (kept in memory only), reported.
    """

    name = "mqtt"

    def __init__(self, settings: MqttSettings, outbox: Outbox,
                 health: Callable[[], dict[str, Any]], outbox_problem: str = "") -> None:
        self.settings = settings
        self.gauge_id, self.prefix, self.client_id = gauge_identity(settings)
        self.outbox, self.outbox_problem = outbox, outbox_problem
        self._health = health
        self._disk = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="mqtt-outbox")
        self._filter = RepeatFilter(settings.decision_repeat_s)
        self._decision_seq = outbox.last_number  # numbering goes on after a restart
        self._latest: MeasurementRecord | None = None
        self._sent_seq = -1
        self._last_measurement_s = -float("inf")
        self._wake = asyncio.Event()  # a new measurement
        self._decision_wake = asyncio.Event()  # a decision in the outbox
        self._pending: set[asyncio.Future] = set()
        self.connected = False
        self.problem = ""
        self._dropped_at_start = outbox.dropped
        self.counters = {"measurements": 0, "decisions": 0, "health": 0, "connects": 0,
                         "decisions_skipped": 0}

    def topic(self, leaf: str) -> str:
        """``<prefix>/<leaf>``."""
        return f"{self.prefix}/{leaf}"

    # ---- fed by the gauge (on the event loop) --------------------------------------------

    def measurement(self, record: MeasurementRecord) -> None:
        """The latest measurement (sent when the rate allows)."""
        self._latest = record
        self._wake.set()

    def decision(self, d: Decision) -> None:
        """A compensation decision: into the outbox (in order), then to the broker."""
        repeats = self._filter.admit(d, time.monotonic())
        if repeats is None:
            self.counters["decisions_skipped"] += 1
            return
        self._decision_seq += 1
        now = time.time()
        body = json.dumps(decision_payload(d, self.gauge_id, self._decision_seq, now,
                                           repeats)).encode()
        fut = asyncio.wrap_future(self._disk.submit(
            self.outbox.put, self.topic("decision"), body, self.settings.qos_decision, now,
            self._decision_seq))
        self._pending.add(fut)
        fut.add_done_callback(self._stored)

    def part(self, record: dict[str, Any]) -> None:
        """A finished part (``PartRecord.as_dict``): through the outbox like the decisions,
        so that none is lost while the broker is away, one message a part."""
        body = json.dumps({"gauge_id": self.gauge_id, **record}).encode()
        fut = asyncio.wrap_future(self._disk.submit(
            self.outbox.put, self.topic("part"), body, self.settings.qos_decision,
            time.time()))
        self._pending.add(fut)
        fut.add_done_callback(self._stored)

    def _stored(self, fut: asyncio.Future) -> None:
        self._pending.discard(fut)
        if fut.cancelled():
            return
        err = fut.exception()
        if err is not None:
            log.error("a decision or part could not be kept for the broker: %s", err)
            self.problem = f"MQTT outbox cannot be written ({err})"
        elif fut.result():
            log.warning("MQTT outbox full: %d oldest messages dropped", fut.result())
        self._decision_wake.set()

    async def _outbox(self, fn: Callable[..., Any], *args: Any) -> Any:
        return await asyncio.get_running_loop().run_in_executor(self._disk, fn, *args)

    # ---- the connection ------------------------------------------------------------------

    def _client(self) -> aiomqtt.Client:
        s = self.settings
        tls = None
        if s.tls_ca is not None:
            tls = aiomqtt.TLSParameters(
                ca_certs=str(s.tls_ca), certfile=None if s.tls_cert is None else str(s.tls_cert),
                keyfile=None if s.tls_key is None else str(s.tls_key),
                cert_reqs=ssl.CERT_REQUIRED, tls_version=ssl.PROTOCOL_TLS_CLIENT)
        return aiomqtt.Client(
            s.host or "", s.port, username=s.username, password=s.password,
            identifier=self.client_id, keepalive=s.keepalive_s, timeout=CONNECT_TIMEOUT_S,
            will=aiomqtt.Will(self.topic("state"), b"offline", qos=s.qos_state, retain=True),
            tls_params=tls)

    async def run(self) -> None:
        """Connect, publish, and connect again after every loss, until cancelled."""
        s = self.settings
        while True:
            try:
                async with self._client() as client:
                    self.connected, self.problem = True, ""
                    self.counters["connects"] += 1
                    log.info("MQTT broker %s:%d connected", s.host, s.port)
                    try:
                        await client.publish(self.topic("state"), b"online", qos=s.qos_state,
                                             retain=True, timeout=PUBLISH_TIMEOUT_S)
                        await self._serve(client)
                    except asyncio.CancelledError:  # a clean stop: say so, then go
                        await asyncio.shield(self._goodbye(client))
                        raise
            except (aiomqtt.MqttError, OSError) as err:
                why = str(err)
                if not self.connected and "timed out" in why:  # aiomqtt's words for no CONNACK
                    why = (f"no answer to the connection within {CONNECT_TIMEOUT_S:g} s "
                           "(TLS on one side only?)")
                if self.connected or not self.problem:
                    log.warning("MQTT broker %s:%d: %s", s.host, s.port, why)
                self.problem = f"MQTT broker {s.host}:{s.port}: {why}"
            finally:
                self.connected = False
            await asyncio.sleep(s.reconnect_s)

    async def _goodbye(self, client: aiomqtt.Client) -> None:
        with contextlib.suppress(aiomqtt.MqttError):
            await client.publish(self.topic("state"), b"offline", qos=self.settings.qos_state,
                                 retain=True, timeout=2.0)

    async def _serve(self, client: aiomqtt.Client) -> None:
        """The decisions and the live stream on one connection, each in a loop of its own: a
        decision waiting for its acknowledgement or for the outbox's disk never holds back a
        measurement (at 50 gauges on a busy host it had let the next one replace it)."""
        tasks = [asyncio.create_task(self._decisions(client)),
                 asyncio.create_task(self._live(client))]
        try:
            done, _ = await asyncio.wait(tasks, return_when=asyncio.FIRST_EXCEPTION)
            for t in done:
                t.result()  # the connection's error, for run() to report
        finally:
            for t in tasks:
                t.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)

    async def _decisions(self, client: aiomqtt.Client) -> None:
        while True:
            self._decision_wake.clear()
            await self._drain(client)
            await self._decision_wake.wait()

    async def _live(self, client: aiomqtt.Client) -> None:
        """The latest measurement at most ``measurement_hz``, health every ``health_s``."""
        s = self.settings
        period_s = 1.0 / s.measurement_hz
        next_health = time.monotonic()
        while True:
            self._wake.clear()
            now = time.monotonic()
            latest = self._latest
            due = self._last_measurement_s + period_s
            if latest is not None and latest.seq != self._sent_seq and now >= due:
                await client.publish(self.topic("measurement"), json.dumps(
                    measurement_payload(latest, self.gauge_id)).encode(),
                    qos=s.qos_measurement, timeout=PUBLISH_TIMEOUT_S)
                self._sent_seq, self._last_measurement_s = latest.seq, now
                self.counters["measurements"] += 1
            if now >= next_health:
                await client.publish(self.topic("health"), json.dumps(
                    {"gauge_id": self.gauge_id, "time": time.time(), **self._health()},
                    default=str).encode(), qos=0, timeout=PUBLISH_TIMEOUT_S)
                self.counters["health"] += 1
                next_health = now + s.health_s
            now = time.monotonic()
            wait_s = next_health - now
            latest = self._latest
            if latest is not None and latest.seq != self._sent_seq:
                wait_s = min(wait_s, self._last_measurement_s + period_s - now)
            if wait_s > 0:
                with contextlib.suppress(TimeoutError):
                    async with asyncio.timeout(wait_s):  # no task per wait (wait_for makes one)
                        await self._wake.wait()

    async def _drain(self, client: aiomqtt.Client) -> None:
        """Send what waits in the outbox, oldest first; each removed once acknowledged."""
        while len(self.outbox):  # the count is kept in memory: no disk read when empty
            batch = await self._outbox(self.outbox.peek, 200)
            if not batch:
                return
            for msg in batch:
                await client.publish(msg.topic, msg.payload, qos=msg.qos,
                                     timeout=PUBLISH_TIMEOUT_S)
                await self._outbox(self.outbox.remove, msg.id)
                self.counters["decisions"] += 1

    async def flush(self) -> None:
        """Wait until every decision handed over so far is in the outbox."""
        if self._pending:
            await asyncio.gather(*list(self._pending), return_exceptions=True)

    def status(self) -> dict[str, Any]:
        """Connection, queue and counters, JSON-ready."""
        s = self.settings
        return {"broker": f"{s.host}:{s.port}", "tls": s.tls_ca is not None,
                "topic_prefix": self.prefix, "connected": self.connected,
                "problem": self.problem or None, "queued_decisions": len(self.outbox),
                "dropped_decisions": self.outbox.dropped, **self.counters}

    def problems(self) -> list[tuple[str, str]]:
        """What is wrong now, as (code, text)."""
        out = []
        if not self.connected and self.problem:
            out.append(("mqtt_unreachable", f"{self.problem} ({len(self.outbox)} decisions "
                                            "kept for it)"))
        if self.outbox_problem:
            out.append(("mqtt_outbox", self.outbox_problem + ": decisions are kept in memory "
                        "only while the broker is away"))
        lost = self.outbox.dropped - self._dropped_at_start
        if lost:
            out.append(("mqtt_decisions_dropped",
                        f"{lost} decisions dropped since the start: the MQTT outbox was full "
                        f"({self.settings.outbox_max} kept for the broker)"))
        return out

    async def close(self) -> None:
        """Finish the outbox writes and close it (after ``run`` was cancelled)."""
        await self.flush()
        await self._outbox(self.outbox.close)
        self._disk.shutdown(wait=True)
