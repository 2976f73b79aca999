"""Prometheus text exposition of the gauge's figures."""

from __future__ import annotations

from service.runtime.feed import MeasurementFeed
from service.runtime.health import HealthReport


def metrics_text(health: HealthReport, feed: MeasurementFeed) -> str:
    """Prometheus text exposition of the gauge's figures."""
    st = health.status()
    p = st["pipeline"]
    cam = st["camera"]["counters"]
    latest = feed.latest
    lines: list[str] = []

    def metric(name: str, kind: str, help_: str, value: float | None, labels: str = "") -> None:
        if value is None:
            return
        lines.append(f"# HELP shaftgauge_{name} {help_}")
        lines.append(f"# TYPE shaftgauge_{name} {kind}")
        lines.append(f"shaftgauge_{name}{labels} {float(value):.9g}")

    metric("healthy", "gauge", "1 when camera, calibration and measurement are fine",
           int(st["healthy"]))
    metric("diameter_mm", "gauge", "Latest measured diameter",
           latest.diameter_mm if latest else None)
    metric("diameter_uncertainty_mm", "gauge", "Standard uncertainty of the latest diameter",
           latest.uncertainty_mm if latest else None)
    metric("measurement_rate_hz", "gauge", "Measurements per second (10 s)", p["rate_hz"])
    metric("frames_total", "counter", "Frames taken from the camera", p["frames_in"])
    metric("measurements_total", "counter", "Frames measured", p["measured"])
    metric("measurements_failed_total", "counter", "Frames without a diameter", p["failed"])
    metric("camera_frames_dropped_total", "counter", "Frames dropped for a slow consumer",
           cam["dropped"])
    metric("camera_frames_failed_total", "counter", "Incomplete frames", cam["failed"])
    metric("camera_missing_packets_total", "counter", "Missing GVSP packets",
           cam["missing_packets"])
    metric("camera_reconnects_total", "counter", "Camera reconnections", cam["reconnects"])
    metric("latency_median_ms", "gauge", "Frame to registers, median",
           p["latency"]["median_ms"])
    metric("latency_p99_ms", "gauge", "Frame to registers, 99th percentile",
           p["latency"]["p99_ms"])
    metric("cumulative_offset_mm", "gauge", "Acknowledged tool-wear offset since reset",
           st["compensation"]["cumulative_offset_mm"])
    metric("modbus_requests_total", "counter", "Modbus requests served",
           st["modbus"]["requests"])
    return "\n".join(lines) + "\n"
