"""The quality export: archived measurements as an AQDEF file over REST and from the CLI."""

from __future__ import annotations

import subprocess
import time

from fastapi.testclient import TestClient

from service.api.app import create_app
from service.serve import Children, build
from tests.aqdef_reading import characteristics
from tests.integration.conftest import SHAFTGAUGE
from tests.unit.plant.test_aqdef import read_aqdef
from tests.unit.service.conftest import make_settings


def test_the_aqdef_export_holds_the_archived_measurements(tmp_path) -> None:
    gauge, _ = build(make_settings(tmp_path, store={"archive_hz": 20.0}), Children())
    with TestClient(create_app(gauge)) as c:
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            gauge.log.flush(2.0)
            if len(gauge.log.measurements()) >= 5:
                break
            time.sleep(0.1)
        r = c.get("/api/v1/export/aqdef", params={"part": "4711"})
        assert r.status_code == 200, r.text
        assert r.headers["content-type"].startswith("text/plain")
        assert r.headers["content-disposition"].endswith('.dfq"')
        header, values = read_aqdef(r.content.decode("cp1252"))
        r_first = r.content
        assert header["1001"] == "4711" and header["2101"] == "30.0000"
        assert len(values) >= 5 and int(r.headers["x-values"]) == len(values)
        assert all(abs(float(v["0001"]) - 30.0) < 0.01 for v in values)
        seqs = [int(v["0014"]) for v in values]
        assert seqs == sorted(seqs)
        # a window before the first measurement: a header and no values
        r = c.get("/api/v1/export/aqdef", params={"to": "2001-01-01T00:00:00"})
        assert r.status_code == 200 and read_aqdef(r.text)[1] == []
        for bad in ({"from": "yesterday"}, {"from": "2026-01-02", "to": "2026-01-01"},
                    {"part": "a\nb"}):
            r = c.get("/api/v1/export/aqdef", params=bad)
            assert r.status_code == 422, (bad, r.text)
        assert "after" in c.get("/api/v1/export/aqdef", params={
            "from": "2026-01-02", "to": "2026-01-01"}).json()["detail"]
    out = tmp_path / "out.dfq"
    done = subprocess.run([SHAFTGAUGE, "export", "aqdef", "--store", str(gauge.log.path),
                           "--output", str(out), "--part", "4711"], capture_output=True,
                          text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    _, from_cli = read_aqdef(out.read_bytes().decode("cp1252"))
    assert len(from_cli) >= len(values)
    assert [v["0001"] for v in from_cli[:len(values)]] == [v["0001"] for v in values]
    # Both as an independent reader takes them: one characteristic (the rows are of no
    # job's feature), its limits the header's, its values the rows'.
    (tmp_path / "api.dfq").write_bytes(r_first)
    for path, expected in ((tmp_path / "api.dfq", values), (out, from_cli)):
        declared, chars = characteristics(path)
        assert declared == len(chars) == 1
        c = chars[0]
        assert (c["nominal"], c["lower"], c["upper"]) == (
            float(header["2101"]), float(header["2110"]), float(header["2111"]))
        assert c["values"] == [float(v["0001"]) for v in expected]
    bad = subprocess.run([SHAFTGAUGE, "export", "aqdef", "--store", str(tmp_path / "no.db"),
                          "--output", str(out)], capture_output=True, text=True, timeout=60)
    assert bad.returncode != 0 and "missing" in bad.stderr


def test_a_gauge_id_of_any_text_makes_a_valid_file_name(tmp_path) -> None:
    gauge, _ = build(make_settings(tmp_path, mqtt={"gauge_id": 'Drehbank "Ü 7"/links'}),
                     Children())
    with TestClient(create_app(gauge)) as c:
        r = c.get("/api/v1/export/aqdef")
        assert r.status_code == 200
        assert 'filename="shaftgauge-Drehbank_7_links-' in r.headers["content-disposition"]
