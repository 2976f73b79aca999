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


def test_the_grafana_dashboard_reads_only_metrics_the_gauge_exports(tmp_path) -> None:
    import json
    import re
    import time
    from pathlib import Path

    from fastapi.testclient import TestClient

    from service.api.app import create_app
    from service.serve import Children, build
    from tests.unit.service.conftest import make_settings

    dashboard = (Path(__file__).resolve().parents[3] / "deploy" / "grafana-dashboard.json")
    wanted = set(re.findall(r"\b((?:shaftgauge|process)_[a-z_]+)", dashboard.read_text()))
    assert json.loads(dashboard.read_text())["panels"]
    gauge, _ = build(make_settings(tmp_path, mqtt={"host": "127.0.0.1", "port": 1}),
                     Children())
    with TestClient(create_app(gauge)) as c:
        # The fused diameter exists once the fusion window has its measurements: waited for,
        # not slept on (0.5 s was too short on a busy machine).
        deadline = time.monotonic() + 20.0
        while time.monotonic() < deadline and (
                gauge.feed.latest is None or gauge.feed.latest.fused_diameter_mm is None):
            time.sleep(0.05)
        exported = set()
        for f in text_string_to_metric_families(c.get("/metrics").text):
            exported |= {s.name for s in f.samples}
    assert wanted - exported == set()
