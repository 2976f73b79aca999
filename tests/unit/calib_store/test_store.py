"""The calibration store: versions, atomic activation, audit, and damaged files left alone."""

from __future__ import annotations

import sqlite3

import pytest

from calib_store.compensation_log import CompensationLog
from calib_store.store import CalibrationStore, StoreError
from drivers.sim.rig import RigConfig, rig_calibration
from tests.integration.conftest import small_disk  # noqa: F401  (a real read-only mount)

CAL_A = rig_calibration(RigConfig())
CAL_B = rig_calibration(RigConfig(triangulation_deg=40.0))


def test_versions_activation_and_audit(tmp_path) -> None:
    store = CalibrationStore(tmp_path / "s.db")
    assert store.active() is None and store.list() == []
    a = store.add(CAL_A, by="technician", note="first", quality={"rms_px": 0.1})
    b = store.add(CAL_B, by="admin", note="second", activate=True)
    info, cal = store.active()
    assert info.id == b and cal == CAL_B and info.created_by == "admin"
    store.activate(a, by="technician")
    assert store.active()[0].id == a
    assert [i.id for i in store.list()] == [b, a]
    assert store.get(a)[0].quality == {"rms_px": 0.1}
    assert [e["action"] for e in store.audit()] == ["activate", "activate", "import", "import"]
    with pytest.raises(KeyError):
        store.activate(999, by="x")
    store.close()


def test_a_restart_resumes_with_the_active_calibration(tmp_path) -> None:
    store = CalibrationStore(tmp_path / "s.db")
    cid = store.add(CAL_B, by="t", activate=True)
    store.close()
    again = CalibrationStore(tmp_path / "s.db", create_if_missing=False)
    info, cal = again.active()
    assert info.id == cid and cal.to_document() == CAL_B.to_document()


def test_a_missing_store_is_reported_not_created_when_not_allowed(tmp_path) -> None:
    with pytest.raises(StoreError, match="missing"):
        CalibrationStore(tmp_path / "gone.db", create_if_missing=False)
    assert not (tmp_path / "gone.db").exists()


@pytest.mark.parametrize("content", [b"this is not a database at all" * 100,
                                     b"SQLite format 3\x00" + b"\xff" * 5000])
def test_a_corrupt_store_is_reported_and_left_untouched(tmp_path, content) -> None:
    path = tmp_path / "bad.db"
    path.write_bytes(content)
    with pytest.raises(StoreError) as err:
        CalibrationStore(path)
    assert str(path) in str(err.value) and "untouched" in str(err.value)
    assert path.read_bytes() == content
    with pytest.raises(StoreError):
        CompensationLog(path)


@pytest.mark.parametrize("create", [True, False])
def test_an_empty_store_is_refused_and_left_untouched(tmp_path, create: bool) -> None:
    """A store truncated to 0 bytes is refused like a damaged one, never replaced by a new,
    empty store (SQLite takes an empty file for a new database)."""
    path = tmp_path / "truncated.db"
    path.write_bytes(b"")
    for opener in (CalibrationStore, CompensationLog):
        with pytest.raises(StoreError, match="empty") as err:
            opener(path, create_if_missing=create)
        assert str(path) in str(err.value) and "untouched" in str(err.value)
    assert path.read_bytes() == b""


def test_a_damaged_stored_document_is_reported(tmp_path) -> None:
    store = CalibrationStore(tmp_path / "s.db")
    cid = store.add(CAL_A, by="t", activate=True)
    db = sqlite3.connect(str(tmp_path / "s.db"))
    db.execute("UPDATE calibrations SET document = '{\"schema\": \"x\"}' WHERE id = ?", (cid,))
    db.commit()
    db.close()
    with pytest.raises(StoreError, match=f"stored calibration {cid} is damaged"):
        store.get(cid)


def test_a_foreign_database_is_refused_and_left_untouched(tmp_path) -> None:
    path = tmp_path / "places.sqlite"
    db = sqlite3.connect(str(path))
    db.execute("CREATE TABLE moz_places (id INTEGER PRIMARY KEY, url TEXT)")
    db.execute("INSERT INTO moz_places (url) VALUES ('https://example.org')")
    db.commit()
    db.close()
    content = path.read_bytes()
    for opener in (CalibrationStore, CompensationLog):
        with pytest.raises(StoreError, match=r"moz_places.*not a shaftgauge store"):
            opener(path)
    assert path.read_bytes() == content
    assert [p.name for p in tmp_path.iterdir()] == ["places.sqlite"]  # no backup, no journal


def test_a_damaged_store_is_reported_in_a_few_lines(tmp_path) -> None:
    """SQLite's integrity check can list thousands of problems; the status names three."""
    path = tmp_path / "s.db"
    db = sqlite3.connect(str(path))
    db.execute("CREATE TABLE calibrations (id INTEGER PRIMARY KEY, document TEXT)")
    db.execute("CREATE INDEX by_document ON calibrations (document)")
    db.executemany("INSERT INTO calibrations (document) VALUES (?)",
                   [("x" * 200 + str(i),) for i in range(3000)])
    db.commit()
    db.close()
    damaged = bytearray(path.read_bytes())
    for at in range(8192, len(damaged) - 4096, 4096 * 7):
        damaged[at + 100:at + 300] = bytes(200)
    path.write_bytes(bytes(damaged))
    with pytest.raises(StoreError, match="damaged") as err:
        CalibrationStore(path)
    text = str(err.value)
    assert "\n" not in text and len(text) < 600 and "more" in text, text
    assert path.read_bytes() == bytes(damaged)


def test_a_read_only_store_says_so(tmp_path, small_disk) -> None:  # noqa: F811
    CalibrationStore(small_disk.path / "s.db").close()
    small_disk.read_only()
    with pytest.raises(StoreError, match="read-only"):
        CalibrationStore(small_disk.path / "s.db", create_if_missing=False)
