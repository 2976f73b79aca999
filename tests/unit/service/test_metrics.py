"""/metrics as Prometheus scrapes it, parsed by prometheus-client's own parser."""

from __future__ import annotations

from prometheus_client.parser import text_string_to_metric_families


def test_metrics_hold_the_histograms_and_the_usual_process_figures(client) -> None:
    import time

    time.sleep(0.5)
    r = client.get("/metrics")
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/plain")
    families = {f.name: f for f in text_string_to_metric_families(r.text)}
    lat = families["shaftgauge_frame_to_registers_seconds"]
    assert lat.type == "histogram"
    count = next(s.value for s in lat.samples if s.name.endswith("_count"))
    assert count >= 1
    stages = {s.labels["stage"] for s in families["shaftgauge_stage_seconds"].samples
              if s.name.endswith("_count")}
    assert stages == {"wait", "measure"}
    assert families["shaftgauge_measurements"].type == "counter"
    assert families["shaftgauge_offset_write_seconds"].type == "histogram"
    for usual in ("process_cpu_seconds", "process_resident_memory_bytes", "python_info"):
        assert usual in families, usual
    assert abs(families["shaftgauge_diameter_mm"].samples[0].value - 30.0) < 0.02
