"""Jobs kept as versions with an audit, the active one, and part records; a store of the
release before jobs gains them with every row kept."""

from __future__ import annotations

import shutil
import sqlite3
from pathlib import Path

import pytest

from calib_store import schema
from calib_store.job_store import JobStore

FIXTURES = Path(__file__).resolve().parents[2] / "fixtures" / "stores"
DOC = {"part_number": "SH-4711", "name": "stepped shaft", "features": [
    {"number": 1, "name": "journal", "nominal_mm": 30.0, "tol_upper_mm": 0.02,
     "tol_lower_mm": -0.02, "tool": 1}]}


def test_versions_the_active_job_and_the_audit(tmp_path) -> None:
    jobs = JobStore(tmp_path / "s.db")
    assert jobs.active() is None and jobs.list() == []
    first = jobs.add(DOC, by="technician (key k-1)", note="from the drawing", activate=True)
    second = jobs.add({**DOC, "name": "stepped shaft, rev B"}, by="technician (key k-1)")
    other = jobs.add({**DOC, "part_number": "FL-12"}, by="admin")
    assert [(j.part_number, j.version) for j in jobs.list()] == [
        ("FL-12", 1), ("SH-4711", 2), ("SH-4711", 1)]
    assert jobs.active().id == first and jobs.get(second).document["name"].endswith("B")
    jobs.activate(second, by="modbus:127.0.0.1")
    assert jobs.active().id == second and not jobs.get(first).active
    assert [(a["action"], a["job_id"]) for a in jobs.audit()] == [
        ("activate", second), ("add", other), ("add", second), ("activate", first),
        ("add", first)]
    with pytest.raises(KeyError, match="no job 99"):
        jobs.activate(99, by="x")
    jobs.close()
    again = JobStore(tmp_path / "s.db", create_if_missing=False)
    assert again.active().id == second  # a restart resumes with it


def test_part_records_newest_first_by_serial_and_page(tmp_path) -> None:
    jobs = JobStore(tmp_path / "s.db")
    jid = jobs.add(DOC, by="t", activate=True)
    for k in range(5):
        jobs.add_part(f"P{k:04d}", 1.8e9 + k, jid, "ok" if k != 3 else "out",
                      [{"feature": 1, "diameter_mm": 30.001 + k / 1000,
                        "uncertainty_mm": 0.0008, "verdict": "ok" if k != 3 else "above"}])
    newest = jobs.parts(limit=2)
    assert [p["serial"] for p in newest] == ["P0004", "P0003"]
    assert newest[1]["features"][0]["verdict"] == "above"
    assert [p["serial"] for p in jobs.parts(limit=10, before_id=newest[1]["id"])] == [
        "P0002", "P0001", "P0000"]
    assert [p["id"] for p in jobs.parts(serial="P0001")] == [2]


def test_a_store_of_the_release_before_jobs_gains_them_keeping_every_row(tmp_path) -> None:
    (fixture,) = FIXTURES.glob("2026-12-06-*.db")
    path = tmp_path / "shaftgauge.db"
    shutil.copy(fixture, path)
    db = sqlite3.connect(str(path))
    assert schema.version_of(db) == 2
    before = {t: db.execute(f'SELECT COUNT(*) FROM "{t}"').fetchone()[0]
              for (t,) in db.execute("SELECT name FROM sqlite_master WHERE type = 'table' "
                                     "AND name NOT LIKE 'sqlite_%'").fetchall()}
    db.close()
    jobs = JobStore(path)
    assert jobs.list() == [] and jobs.parts() == []
    jid = jobs.add(DOC, by="t", activate=True)
    assert jobs.active().id == jid
    jobs.close()
    db = sqlite3.connect(str(path))
    assert schema.version_of(db) == schema.SCHEMA_VERSION >= 3
    for table, n in before.items():
        assert db.execute(f'SELECT COUNT(*) FROM "{table}"').fetchone()[0] == n, table
    assert "feature" in {r[1] for r in db.execute("PRAGMA table_info(measurements)")}
    db.close()
    assert len(list(tmp_path.glob("shaftgauge.db.v2-*.bak"))) == 1  # backed up first
