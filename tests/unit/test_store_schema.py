"""The store's life: stores written by earlier releases (tests/fixtures/stores, each made by
that release's own serve) open with every row kept, backed up first; a store of a newer
schema is refused naming both versions and left as it was; backup, restore and migrate from
the command line."""

from __future__ import annotations

import json
import shutil
import sqlite3
from pathlib import Path

import pytest

from calib_store import schema
from calib_store.compensation_log import CompensationLog
from calib_store.gauge_studies import GaugeStudyStore
from calib_store.store import CalibrationStore, StoreError
from service import cli

FIXTURES = sorted((Path(__file__).resolve().parents[1] / "fixtures" / "stores").glob("*.db"))


def _counts(path: Path) -> dict[str, int]:
    db = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
    try:
        tables = [r[0] for r in db.execute(
            "SELECT name FROM sqlite_master WHERE type = 'table' AND name NOT LIKE 'sqlite_%'")]
        return {t: db.execute(f'SELECT COUNT(*) FROM "{t}"').fetchone()[0] for t in tables}
    finally:
        db.close()


def _open_all(path: Path) -> tuple[CalibrationStore, CompensationLog, GaugeStudyStore]:
    return CalibrationStore(path), CompensationLog(path), GaugeStudyStore(path)


def test_stores_of_five_earlier_releases_are_here() -> None:
    assert len(FIXTURES) >= 5, FIXTURES


@pytest.mark.parametrize("fixture", FIXTURES, ids=lambda p: p.stem)
def test_a_store_of_an_earlier_release_opens_with_every_row_kept(fixture: Path, tmp_path
                                                                ) -> None:
    path = tmp_path / "shaftgauge.db"
    shutil.copy(fixture, path)
    before = _counts(path)
    assert sum(before.values()) > 0
    store, log_, studies = _open_all(path)
    try:
        _, calibration = store.active()
        assert calibration.image_size
        assert log_.decisions(limit=1000)
        studies.list()
    finally:
        log_.close()
        store.close()
    after = _counts(path)
    assert {t: after[t] for t in before} == before
    assert set(after) >= {"calibrations", "compensation_decisions", "measurements",
                          "gauge_studies", "gauge_values"}
    db = sqlite3.connect(str(path))
    assert schema.version_of(db) == schema.SCHEMA_VERSION
    db.close()
    kept = list(tmp_path.glob("shaftgauge.db.v*-*.bak"))  # v0: before versions
    assert len(kept) == 1 and _counts(kept[0]) == before


def test_the_store_of_the_release_with_jobs_gains_a_state_per_entry(tmp_path) -> None:
    """The release before a state per tool: its single channel's state becomes its tool's
    own entry's (tool 1: the settings' single feature), its decisions that tool's."""
    (fixture,) = (f for f in FIXTURES if f.name.startswith("2026-12-06.2-"))
    path = tmp_path / "shaftgauge.db"
    shutil.copy(fixture, path)
    db = sqlite3.connect(str(path))
    single = db.execute("SELECT state FROM compensation_state").fetchone()[0]
    db.close()
    log_ = CompensationLog(path)
    try:
        assert log_.load_state(1) == json.loads(single) and log_.load_state(2) is None
        assert {r["tool"] for r in log_.decisions(limit=1000)} == {1}
    finally:
        log_.close()
    assert _counts(path)["entry_states"] == 1 and _counts(path)["parts"] > 0


def test_the_store_of_the_release_with_a_state_per_tool_keeps_each_tools(tmp_path) -> None:
    """The release before offset entries (a job of two tools in force): each tool's state
    is its own entry's, every row kept, the old tables as they were."""
    (fixture,) = (f for f in FIXTURES if f.name.startswith("2026-12-07-"))
    path = tmp_path / "shaftgauge.db"
    shutil.copy(fixture, path)
    before = _counts(path)
    db = sqlite3.connect(str(path))
    tools = dict(db.execute("SELECT tool, state FROM tool_states").fetchall())
    db.close()
    assert sorted(tools) == [1, 2]
    log_ = CompensationLog(path)
    try:
        for t, state in tools.items():
            assert log_.load_state(t) == json.loads(state)
            assert log_.load_state(t, 10000 + t) is None
        assert None not in {r["tool"] for r in log_.decisions(limit=1000)}
    finally:
        log_.close()
    after = _counts(path)
    assert {t: after[t] for t in before} == before and after["entry_states"] == 2
    assert len(list(tmp_path.glob("shaftgauge.db.v4-*.bak"))) == 1


def test_a_new_store_is_made_at_the_latest_version_without_a_backup(tmp_path) -> None:
    path = tmp_path / "new.db"
    CalibrationStore(path).close()
    db = sqlite3.connect(str(path))
    assert schema.version_of(db) == schema.SCHEMA_VERSION
    db.close()
    assert not list(tmp_path.glob("*.bak"))


def test_a_store_of_a_newer_release_is_refused_and_left_as_it_was(tmp_path) -> None:
    path = tmp_path / "newer.db"
    CalibrationStore(path).close()
    db = sqlite3.connect(str(path))
    db.execute(f"PRAGMA user_version = {schema.SCHEMA_VERSION + 1}")
    db.commit()
    db.close()
    before = path.read_bytes()
    with pytest.raises(StoreError) as err:
        CompensationLog(path)
    text = str(err.value)
    assert f"schema version {schema.SCHEMA_VERSION + 1}" in text
    assert f"up to {schema.SCHEMA_VERSION}" in text and str(path) in text
    assert path.read_bytes() == before


def test_a_migration_that_fails_leaves_the_store_at_its_version(tmp_path, monkeypatch) -> None:
    path = tmp_path / "old.db"
    shutil.copy(FIXTURES[0], path)

    def broken(db: sqlite3.Connection) -> None:
        db.execute("CREATE TABLE half_done (x INTEGER)")
        raise sqlite3.OperationalError("disk I/O error")

    monkeypatch.setattr(schema, "MIGRATIONS", (schema.Migration(1, "broken", broken),))
    with pytest.raises(StoreError):
        CalibrationStore(path)
    db = sqlite3.connect(str(path))
    assert schema.version_of(db) == 0
    assert "half_done" not in _counts(path)
    db.close()


def _cli(*args: str, capsys) -> tuple[int, dict | str]:
    code = cli.main(list(args))
    out, err = capsys.readouterr()
    return code, (json.loads(out) if code == 0 else err)


def test_version_migrate_backup_and_restore_from_the_command_line(tmp_path, capsys) -> None:
    path = tmp_path / "shaftgauge.db"
    shutil.copy(FIXTURES[-1], path)  # the release before the latest schema
    before = _counts(path)
    db = sqlite3.connect(str(path))
    was = schema.version_of(db)
    db.close()
    code, out = _cli("store", "version", "--store", str(path), capsys=capsys)
    assert code == 0 and out["schema_version"] == was < schema.SCHEMA_VERSION and out["pending"]
    code, out = _cli("store", "migrate", "--dry-run", "--store", str(path), capsys=capsys)
    assert code == 0 and out["pending"] and "applied" not in out
    assert _counts(path) == before
    code, out = _cli("store", "migrate", "--store", str(path), capsys=capsys)
    assert code == 0 and out["applied"] == [m.version for m in schema.MIGRATIONS
                                            if m.version > was]
    assert out["schema_version"] == schema.SCHEMA_VERSION
    code, out = _cli("store", "backup", "--store", str(path), str(tmp_path / "b.db"),
                     capsys=capsys)
    assert code == 0
    assert {t: n for t, n in _counts(tmp_path / "b.db").items() if t in before} == before
    code, err = _cli("store", "backup", "--store", str(path), str(tmp_path / "b.db"),
                     capsys=capsys)
    assert code != 0 and "exists already" in err
    # A decision more, then the backup restored: the store is the backup's again, and the
    # store it replaced is kept.
    log_ = CompensationLog(path)
    log_.put_value("marker", "after the backup")
    assert log_.get_value("marker") == "after the backup"
    log_.close()
    code, out = _cli("store", "restore", "--store", str(path), str(tmp_path / "b.db"),
                     capsys=capsys)
    assert code == 0 and Path(out["kept"]).exists()
    assert _counts(path) == _counts(tmp_path / "b.db")
    store, log2, _ = _open_all(path)
    assert store.active() is not None
    assert log2.get_value("marker") is None
    log2.close()
    store.close()


def test_the_command_line_names_a_missing_or_foreign_file(tmp_path, capsys) -> None:
    code, err = _cli("store", "version", "--store", str(tmp_path / "none.db"), capsys=capsys)
    assert code != 0 and "no such store file" in err
    junk = tmp_path / "junk.db"
    junk.write_bytes(b"not a database at all" * 100)
    code, err = _cli("store", "backup", "--store", str(junk), str(tmp_path / "x.db"),
                     capsys=capsys)
    assert code != 0 and "junk.db" in err and "Traceback" not in err


def test_a_version_1_store_gains_the_archive_s_form_columns_keeping_its_rows(tmp_path
                                                                           ) -> None:
    path = tmp_path / "shaftgauge.db"
    db = sqlite3.connect(str(path))
    schema.MIGRATIONS[0].apply(db)
    db.execute("INSERT INTO measurements (seq, wall_time, status, diameter_mm) "
               "VALUES (7, 1.8e9, 'ok', 30.001)")
    db.execute("PRAGMA user_version = 1")
    db.commit()
    db.close()
    store, log_, _ = _open_all(path)
    try:
        (row,) = log_.measurements()
        assert row["seq"] == 7 and row["diameter_mm"] == 30.001
        assert row["tir_mm"] is None and row["ront_mm"] is None
    finally:
        log_.close()
        store.close()
    assert len(list(tmp_path.glob("shaftgauge.db.v1-*.bak"))) == 1
