"""A backup taken while ``serve`` writes decisions and measurements is a whole store: it
restores to a file that opens, with its calibration and its rows."""

from __future__ import annotations

import json
import sqlite3
import subprocess
import time

from calib_store.compensation_log import CompensationLog
from calib_store.store import CalibrationStore
from tests.e2e.conftest import start_service, stop_service, wait_ready
from tests.integration.conftest import SHAFTGAUGE


def _run(*args: str) -> dict:
    out = subprocess.run([SHAFTGAUGE, "store", *args], capture_output=True, text=True,
                         timeout=60)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout)


def test_a_backup_taken_while_serving_restores_to_a_store_that_opens(tmp_path) -> None:
    svc = start_service(tmp_path)
    store = svc.data / "gauge.db"
    try:
        assert wait_ready(svc)
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            with sqlite3.connect(f"file:{store}?mode=ro", uri=True) as db:
                if db.execute("SELECT COUNT(*) FROM measurements").fetchone()[0] >= 20:
                    break
            time.sleep(0.5)
        backups = []
        for i in range(3):  # while the service goes on writing
            backups.append(_run("backup", "--store", str(store), str(tmp_path / f"b{i}.db")))
            time.sleep(1.0)
        assert svc.proc.poll() is None
    finally:
        stop_service(svc)
    restored = tmp_path / "restored.db"
    out = _run("restore", "--store", str(restored), backups[-1]["backup"])
    assert out["restored"] == str(restored) and "kept" not in out
    with sqlite3.connect(str(restored)) as db:
        assert db.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
        rows = db.execute("SELECT COUNT(*) FROM measurements").fetchone()[0]
    assert rows >= 20
    cal, log_ = CalibrationStore(restored, create_if_missing=False), CompensationLog(restored)
    try:
        assert cal.active() is not None
        assert len(log_.measurements()) == rows
    finally:
        log_.close()
        cal.close()
