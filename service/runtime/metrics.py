"""The gauge's figures for Prometheus (prometheus-client): histograms observed as things
happen, and the counters and gauges of the status read at each scrape.

One registry per gauge (several gauges in one test process never share figures). Names:
``shaftgauge_*``; the process and Python collectors' usual ones (``process_cpu_seconds_total``,
``process_resident_memory_bytes``, ``python_gc_*``) that the common Grafana dashboards read.
"""

from __future__ import annotations

from collections.abc import Iterator

from prometheus_client import (
    CONTENT_TYPE_LATEST,
    CollectorRegistry,
    GCCollector,
    Histogram,
    PlatformCollector,
    ProcessCollector,
    generate_latest,
)
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, Metric
from prometheus_client.registry import Collector

from drivers.plc.client import Outcome
from service.measurement_record import MeasurementRecord
from service.runtime.health import HealthReport

# Frame -> registers is milliseconds; an offset write, tens of ms to seconds.
LATENCY_BUCKETS_S = (0.001, 0.002, 0.003, 0.005, 0.0075, 0.01, 0.015, 0.02, 0.03, 0.05,
                     0.1, 0.25, 0.5, 1.0)
STAGE_BUCKETS_S = (0.0005, 0.001, 0.002, 0.003, 0.005, 0.0075, 0.01, 0.02, 0.05, 0.1, 0.5)
WRITE_BUCKETS_S = (0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0)


class StatusCollector(Collector):
    """The status's counters and gauges, read when Prometheus scrapes."""

    def __init__(self, health: HealthReport) -> None:
        self.health = health

    def _features(self) -> Iterator[Metric]:
        """Per feature of the job in force (at most ``MAX_FEATURES`` label sets: only the
        job in force's), and the parts by verdict."""
        jobs = self.health.jobs
        if jobs is None or jobs.job is None:
            return
        diameter = GaugeMetricFamily("shaftgauge_feature_diameter_mm", "Latest diameter of "
                                     "each feature of the job in force", labels=["feature",
                                                                                  "name"])
        deviation = GaugeMetricFamily("shaftgauge_feature_deviation_mm", "Latest deviation "
                                      "of each feature from its nominal",
                                      labels=["feature", "name"])
        for f in jobs.job.features:
            r = jobs.latest.get(f.number)
            if r is not None and r.diameter_mm is not None:
                diameter.add_metric([str(f.number), f.name], r.diameter_mm)
                if r.deviation_mm is not None:
                    deviation.add_metric([str(f.number), f.name], r.deviation_mm)
        parts = CounterMetricFamily("shaftgauge_parts", "Parts recorded since the start, by "
                                    "verdict", labels=["verdict"])
        for verdict, n in jobs.part_log.counts.items():
            parts.add_metric([verdict], n)
        yield from (diameter, deviation, parts)

    def _offsets(self) -> Metric:
        """Each offset entry's cumulative offset (labels ``tool``, its T number, and
        ``entry``, its offset number or empty for the tool's own; as many label sets as the
        job in force has entries)."""
        cumulative = GaugeMetricFamily("shaftgauge_cumulative_offset_mm", "Acknowledged "
                                       "tool-wear offset since reset, by offset entry",
                                       labels=["tool", "entry"])
        for e, ch in self.health.compensation.in_force():
            cumulative.add_metric([str(e.tool), "" if e.number is None else str(e.number)],
                                  ch.controller.cumulative_mm)
        return cumulative

    def collect(self) -> Iterator[Metric]:
        st = self.health.status()
        p, cam = st["pipeline"], st["camera"]["counters"]
        latest = self.health.feed.latest

        def gauge(name: str, help_: str, value: float | None) -> Iterator[Metric]:
            if value is not None:
                yield GaugeMetricFamily(f"shaftgauge_{name}", help_, value=float(value))

        def counter(name: str, help_: str, value: float) -> Iterator[Metric]:
            yield CounterMetricFamily(f"shaftgauge_{name}", help_, value=float(value))

        yield from gauge("healthy", "1 when camera, calibration and measurement are fine",
                         int(st["healthy"]))
        yield from gauge("diameter_mm", "Latest measured diameter",
                         latest.diameter_mm if latest else None)
        yield from gauge("diameter_uncertainty_mm", "Standard uncertainty of the latest "
                         "diameter", latest.uncertainty_mm if latest else None)
        yield from gauge("fused_diameter_mm", "Latest fused diameter",
                         latest.fused_diameter_mm if latest else None)
        yield from gauge("deviation_mm", "Latest deviation from the nominal",
                         latest.deviation_mm if latest else None)
        yield from gauge("measurement_rate_hz", "Measurements per second (10 s)",
                         p["rate_hz"])
        yield from self._features()
        yield self._offsets()
        yield from gauge("problems", "Problems reported now", len(st["problems"]))
        yield from counter("frames", "Frames taken from the camera", p["frames_in"])
        yield from counter("measurements", "Frames measured", p["measured"])
        yield from counter("measurements_failed", "Frames without a diameter", p["failed"])
        yield from counter("camera_frames_dropped", "Frames dropped for a slow consumer",
                           cam["dropped"])
        yield from counter("camera_frames_failed", "Incomplete frames", cam["failed"])
        yield from counter("camera_missing_packets", "Missing GVSP packets",
                           cam["missing_packets"])
        yield from counter("camera_reconnects", "Camera reconnections", cam["reconnects"])
        yield from counter("modbus_requests", "Modbus requests served",
                           st["modbus"]["requests"])
        yield from counter("modbus_refused_connections",
                           "Modbus clients disconnected (not allowed, or too many)",
                           st["modbus"]["refused_connections"])
        yield from counter("modbus_refused_writes", "Modbus writes from clients that may not "
                           "write", st["modbus"]["refused_writes"])
        yield from counter("api_wrong_keys", "API requests with a wrong key",
                           st["api"]["wrong_keys"])
        yield from counter("modbus_refused_handshakes", "Modbus/TCP Security clients refused "
                           "at the TLS handshake", st["modbus"]["refused_handshakes"])
        mqtt = st["plant"].get("mqtt")
        if mqtt is not None:
            yield from gauge("mqtt_connected", "1 while the MQTT broker is connected",
                             int(mqtt["connected"]))
            yield from gauge("mqtt_queued_decisions", "Decisions waiting for the broker",
                             mqtt["queued_decisions"])
            yield from counter("mqtt_messages_published", "Messages the broker took",
                               mqtt["measurements"] + mqtt["decisions"] + mqtt["health"])
            yield from counter("mqtt_decisions_dropped", "Decisions dropped (outbox full)",
                               mqtt["dropped_decisions"])


class GaugeMetrics:
    """The registry of one gauge and its live histograms.

    Parameters
    ----------
    health : HealthReport
        Read at each scrape.
    """

    def __init__(self, health: HealthReport) -> None:
        self.registry = CollectorRegistry(auto_describe=True)
        for c in (ProcessCollector, PlatformCollector, GCCollector):
            c(registry=self.registry)
        self.registry.register(StatusCollector(health))
        self.latency = Histogram(
            "shaftgauge_frame_to_registers_seconds", "Frame received to registers updated",
            buckets=LATENCY_BUCKETS_S, registry=self.registry)
        self.stage = Histogram(
            "shaftgauge_stage_seconds", "Time of one frame in each stage: waiting for a "
            "worker (wait), measuring (measure)", ["stage"], buckets=STAGE_BUCKETS_S,
            registry=self.registry)
        self.offset_write = Histogram(
            "shaftgauge_offset_write_seconds", "Offset write to the CNC's acknowledgement, "
            "by outcome", ["outcome"], buckets=WRITE_BUCKETS_S, registry=self.registry)
        for outcome in Outcome:  # every series there from the start (zeros until used)
            self.offset_write.labels(outcome.value)
        # Bound once: a labels() lookup takes a lock and a dict per call, twice a frame.
        self._stages = {stage: self.stage.labels(stage) for stage in ("wait", "measure")}

    def record(self, record: MeasurementRecord) -> None:
        """A published record (a feed listener)."""
        self.latency.observe(record.latency_ms / 1000.0)

    def stage_time(self, stage: str, seconds: float) -> None:
        """A frame's time in one stage (thread-safe: called from the worker threads)."""
        self._stages[stage].observe(seconds)

    def write_time(self, outcome: str, seconds: float) -> None:
        """An offset write's round trip."""
        self.offset_write.labels(outcome).observe(seconds)

    def exposition(self) -> tuple[bytes, str]:
        """The text exposition and its content type."""
        return generate_latest(self.registry), CONTENT_TYPE_LATEST
