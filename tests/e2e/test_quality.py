"""Quality on the embedded default and in the browser: the SPC figures from the first
seconds, a type-1 study of 25 values on the simulated master, and the SPC view and the study
driven in Debian's Chromium."""

from __future__ import annotations

import re
import sqlite3
import subprocess
import time
from pathlib import Path

import httpx
import pytest
from playwright.sync_api import expect

from drivers.plc.registers import FaultBit
from drivers.sim.control import control
from tests.aqdef_reading import characteristics
from tests.e2e.conftest import (
    TECH_KEY,
    UI_WAIT_MS,
    start_service,
    stop_service,
    wait_for_js,
    wait_ready,
)
from tests.e2e.test_dashboard import enter_key, open_page, shot
from tests.faults.test_cnc_trust import read_register
from tests.integration.conftest import SHAFTGAUGE
from tests.waiting import until

FAST = """
[measurement]
fuse_frames = 3
[spc]
subgroup_size = 4
member_spacing = 3
every_s = 0
baseline_subgroups = 3
"""


def archive_per_feature(svc, tmp_path: Path) -> None:
    """``shaftgauge export aqdef`` on the embedded default's store, once a whole part is
    archived, as an independent reader takes it: a characteristic a feature of the stepped
    shaft, each with its feature's limits, no value out of them that was in tolerance (the
    four features' diameters, 26 to 34 mm, were one characteristic with 30 mm's limits)."""
    until(lambda: svc.get("/api/v1/parts").json()["items"], "no part finished")
    store, out = tmp_path / "data" / "gauge.db", tmp_path / "archive.dfq"
    done = subprocess.run([SHAFTGAUGE, "export", "aqdef", "--store", str(store), "--output",
                           str(out)], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    declared, chars = characteristics(out)
    assert declared == len(chars)
    job_id = svc.get("/api/v1/status").json()["job"]["job"]["id"]
    features = svc.get(f"/api/v1/jobs/{job_id}").json()["document"]["features"]
    diameters = {c["description"]: c for c in chars if c["description"].startswith("diam")}
    assert sorted(diameters) == [f"diameter feature {f['number']}" for f in features]
    with sqlite3.connect(store) as db:
        out_rows = db.execute("SELECT feature, COALESCE(fused_diameter_mm, diameter_mm) FROM "
                              "measurements WHERE status = 'ok' AND in_tolerance = 0").fetchall()
    for f in features:
        c = diameters[f"diameter feature {f['number']}"]
        assert (c["lower"], c["upper"]) == pytest.approx(
            (f["nominal_mm"] + f["tol_lower_mm"], f["nominal_mm"] + f["tol_upper_mm"]))
        assert c["values"], c
        out_of_spec = [v for v in c["values"] if not c["lower"] <= v <= c["upper"]]
        assert all(any(n == f["number"] and abs(v - d) <= 0.5e-4 for n, d in out_rows)
                   for v in out_of_spec), (f, out_of_spec)
    print(f"\nembedded default archive: {declared} characteristics, "
          f"{sum(len(c['values']) for c in chars)} values")


def test_the_embedded_default_fills_spc_and_runs_a_study(tmp_path: Path) -> None:
    svc = start_service(tmp_path, embedded=True)
    try:
        assert wait_ready(svc)
        st = svc.get("/api/v1/status").json()
        comp = svc.get("/api/v1/compensation").json()
        # Its loop closed on the simulated CNC (issue 60), a segment a feature a part.
        assert comp["settings"]["nominal_mm"] == 30.0 and not comp["settings"]["shadow"]
        assert comp["settings"]["judge"] == "segment"
        assert st["job"]["job"]["part_number"] == "DEMO-4" and st["job"]["job"]["tools"] == 2
        assert st["compensation"]["state"] != "alarm"
        deadline, spc = time.monotonic() + 30, {}
        while time.monotonic() < deadline and spc.get("cpk") is None:
            time.sleep(1)
            spc = svc.get("/api/v1/spc").json()
        assert spc["cpk"] is not None and spc["n"] >= 5, spc
        print(f"\nembedded default SPC after {30 - (deadline - time.monotonic()):.0f} s: "
              f"n {spc['n']}, Cpk {spc['cpk']:.2f}")
        archive_per_feature(svc, tmp_path)
        # The embedded default turns a stepped shaft: the technician clamps the master.
        assert control(svc.control_port, {"set": {"diameter_mm": 30.0}})["ok"]
        r = httpx.post(svc.url + "/api/v1/gauge-studies", timeout=10,
                       json={"certified_mm": 30.0, "n": 25}, headers={"X-API-Key": TECH_KEY})
        assert r.status_code == 422 and "name the one" in r.text, r.text  # four features
        r = httpx.post(svc.url + "/api/v1/gauge-studies", timeout=10,
                       json={"certified_mm": 30.0, "n": 25, "feature": 1},
                       headers={"X-API-Key": TECH_KEY})
        assert r.status_code == 202, r.text
        deadline, st = time.monotonic() + 90, {}
        while time.monotonic() < deadline:
            st = svc.get("/api/v1/gauge-studies").json()
            if st["running"] is None:
                break
            time.sleep(1)
        res = st["items"][0]["result"]
        assert st["items"][0]["state"] == "done", st["items"][0]
        print(f"embedded default study: n {res['n']}, Cg {res['cg']:.2f}, Cgk {res['cgk']:.2f},"
              f" bias {res['bias'] * 1000:.2f} um, s_g {res['s_g'] * 1000:.2f} um")
        assert res["n"] == 25 and res["cg"] is not None and res["cgk"] is not None
        assert res["capable"], res
    finally:
        stop_service(svc)


def test_spc_view_and_a_study_from_the_technician_view(tmp_path: Path, browser) -> None:
    svc = start_service(tmp_path, fps=25.0, extra_toml=FAST)
    try:
        assert wait_ready(svc)
        page = open_page(browser, svc.url + "/ui/#spc")
        expect(page.locator("#link")).to_have_text("live", timeout=UI_WAIT_MS)
        expect(page.locator("#spc-baseline")).to_have_text("limits set", timeout=30000)
        expect(page.locator("#spc-cpk-pill")).to_contain_text("Cpk ", timeout=UI_WAIT_MS)
        assert page.locator("#spc-cpk-pill").inner_text() != "Cpk \u2013"  # a number
        expect(page.locator("#spc-cpk")).to_contain_text("95 %")
        page.wait_for_timeout(1500)
        shot(page, "spc-view")
        assert not page.errors  # type: ignore[attr-defined]

        page.goto(svc.url + "/ui/#technician")
        enter_key(page)
        page.fill("#study-mm", "30.0")
        page.fill("#study-n", "25")
        page.click("#study-run")
        expect(page.locator("#study-msg")).to_contain_text("values", timeout=UI_WAIT_MS)
        expect(page.locator("#study-msg")).to_have_text(re.compile(r"Cgk [\d.]+: capable"),
                                                        timeout=60000)
        expect(page.locator("#studies tr").first.locator("td").last).to_have_text("capable")
        page.locator("#studies").scroll_into_view_if_needed()
        page.wait_for_timeout(500)
        shot(page, "gauge-study")

        # a master 20 um off its certificate (T = 0.1 mm here): Cgk < 0, offsets blocked
        page.fill("#study-mm", "30.02")
        page.click("#study-run")
        expect(page.locator("#study-msg")).to_contain_text("Offsets blocked", timeout=60000)
        expect(page.locator("#studies tr").first.locator("td").last).to_contain_text(
            "not capable: Cgk")
        assert read_register(svc.modbus_port, "faults") & FaultBit.GAUGE_STUDY_FAILED
        page.goto(svc.url + "/ui/#operator")
        expect(page.locator("#problems")).to_contain_text("gauge study", timeout=UI_WAIT_MS)
        expect(page.locator("#problems")).to_contain_text("only proposed")
        wait_for_js(page, "document.getElementById('frame').naturalWidth > 0")
        page.evaluate("window.scrollTo(0, 0)")
        shot(page, "gauge-study-failed-operator")
        assert not page.errors  # type: ignore[attr-defined]
    finally:
        stop_service(svc)
