"""The decision log: runs of quiet decisions are one row, writes are durable before they are
carried out, retention by age and rows, queries on an index, a failing disk loses nothing."""

from __future__ import annotations

import sqlite3
import time
from dataclasses import asdict

import pytest

from calib_store.compensation_log import CompensationLog, LogRetention
from service.compensation import QUIET_KINDS, ControllerState, Decision, Kind
from tests.integration.conftest import small_disk  # noqa: F401  (a real full disk)


class Log(CompensationLog):
    """The log as the offset channel feeds it: decisions and states from the controller."""

    def submit(self, decision, wall_time, state, durable=False,  # type: ignore[override]
               tool=1, entry=0):
        return super().submit(decision.as_dict(), wall_time, asdict(state),
                              quiet=decision.kind in QUIET_KINDS, durable=durable, tool=tool,
                              entry=entry)

    def record(self, decision, wall_time, state):  # type: ignore[override]
        self.submit(decision, wall_time, state, durable=True).result()


def held(code: str = "no_nominal", seq: int = 1, shadow: bool = False) -> Decision:
    return Decision(Kind.HELD, f"held ({code})", 0.0, measurement_seq=seq, code=code,
                    shadow=shadow)


def test_a_run_of_identical_quiet_decisions_is_one_row(tmp_path) -> None:
    log = Log(tmp_path / "g.db")
    t0 = time.time()
    for i in range(1000):
        log.submit(held(seq=i), t0 + i * 0.1, ControllerState(last_measurement_seq=i))
    assert log.flush(30.0)  # every submission written (a busy host's thread lags)
    rows = log.decisions(limit=10)
    assert len(rows) == 1
    r = rows[0]
    assert r["count"] == 1000 and r["code"] == "no_nominal"
    assert r["measurement_seq"] == 0 and r["last_measurement_seq"] == 999
    assert r["wall_time"] == pytest.approx(t0) and r["last_time"] == pytest.approx(t0 + 99.9)
    assert log.load_state()["last_measurement_seq"] == 999
    log.close()


def test_a_significant_decision_ends_the_runs(tmp_path) -> None:
    log = Log(tmp_path / "g.db")
    st = ControllerState()
    for _ in range(3):
        log.submit(held("filling_window"), time.time(), st)
        log.submit(held("deadband"), time.time(), st)
        log.submit(held("filling_window"), time.time(), st)   # joins its own run
    log.record(Decision(Kind.APPLIED, "applied", 0.0, offset_seq=1, offset_mm=-0.001,
                        code="applied"), time.time(), st)
    log.submit(held("deadband"), time.time(), st)
    assert log.flush(30.0)  # every submission written (a busy host's thread lags)
    rows = log.decisions(limit=10)
    assert [(r["kind"], r["code"], r["count"]) for r in reversed(rows)] == [
        ("held", "filling_window", 6), ("held", "deadband", 3), ("applied", "applied", 1),
        ("held", "deadband", 1)]
    assert [r["kind"] for r in log.decisions(kinds=("applied",))] == ["applied"]
    log.close()


def test_each_entry_keeps_its_own_state_and_runs(tmp_path) -> None:
    """Each offset entry's state apart from the others' (a tool's own and another offset of
    the same tool too), each decision named by its entry, and an entry's quiet run not
    joined by another's."""
    log = Log(tmp_path / "g.db")
    for i in range(4):
        log.submit(held(seq=i), time.time(), ControllerState(last_measurement_seq=i))
        log.submit(held(seq=i), time.time(), ControllerState(last_measurement_seq=10 + i),
                   tool=2)
        log.submit(held(seq=i), time.time(), ControllerState(last_measurement_seq=20 + i),
                   tool=2, entry=10012)
    assert log.flush(30.0)  # every submission written (a busy host's thread lags)
    rows = log.decisions(limit=10)
    assert sorted((r["tool"], r["entry"], r["count"]) for r in rows) == [
        (1, 0, 4), (2, 0, 4), (2, 10012, 4)]
    assert log.load_state()["last_measurement_seq"] == 3
    assert log.load_state(2)["last_measurement_seq"] == 13
    assert log.load_state(2, 10012)["last_measurement_seq"] == 23
    assert log.load_state(3) is None and log.load_state(2, 10013) is None
    log.close()
    again = Log(tmp_path / "g.db")
    assert again.load_state(2, 10012)["last_measurement_seq"] == 23
    again.close()


def test_the_kind_query_uses_an_index(tmp_path) -> None:
    log = Log(tmp_path / "g.db")
    db = sqlite3.connect(tmp_path / "g.db")
    plan = " ".join(str(r) for r in db.execute(
        "EXPLAIN QUERY PLAN SELECT * FROM compensation_decisions WHERE kind IN ('write') "
        "ORDER BY id DESC LIMIT 10"))
    assert "compensation_decisions_kind" in plan, plan
    db.close()
    log.close()


def test_retention_by_rows_and_age(tmp_path) -> None:
    log = Log(tmp_path / "g.db", retention=LogRetention(
        max_age_days=1.0, max_rows=50, prune_every_s=0.0))
    st = ControllerState()
    old = time.time() - 3 * 86400.0
    for i in range(20):  # three days old: beyond the age
        log.record(Decision(Kind.RESET, "reset", 0.0, code="reset"), old + i, st)
    for i in range(120):
        log.record(Decision(Kind.APPLIED, "applied", 0.0, offset_seq=i, code="applied"),
                   time.time(), st)
    rows = log.decisions(limit=5000)
    assert len(rows) == 50 and all(r["kind"] == "applied" for r in rows)
    assert rows[0]["offset_seq"] == 119  # the newest kept
    log.close()


def test_the_measurement_archive_keeps_the_newest_rows(tmp_path) -> None:
    log = Log(tmp_path / "g.db", retention=LogRetention(prune_every_s=0.0,
                                                        max_measurements=5))
    for seq in range(1, 13):
        log.submit_measurement({"seq": seq, "wall_time": 1000.0 + seq, "status": "ok",
                                "diameter_mm": 30.0})
        log.flush(5.0)
    rows = log.measurements()
    assert [r["seq"] for r in rows] == [8, 9, 10, 11, 12]
    assert [r["seq"] for r in log.measurements(1010.0, 1011.0)] == [10, 11]
    log.close()


def test_a_durable_decision_is_committed_before_its_future_resolves(tmp_path) -> None:
    log = Log(tmp_path / "g.db")
    fut = log.submit(Decision(Kind.WRITE, "write", 0.0, offset_seq=3, code="write"),
                     time.time(), ControllerState(offset_seq=3, pending_seq=3,
                                                  state="pending"), durable=True)
    fut.result(5)
    other = sqlite3.connect(tmp_path / "g.db")  # another reader sees it at once
    assert other.execute("SELECT kind, offset_seq FROM compensation_decisions").fetchall() == [
        ("write", 3)]
    other.close()
    log.close()


def test_values_survive_a_reopen(tmp_path) -> None:
    log = Log(tmp_path / "g.db")
    log.put_value("measurement_seq_reserved", 20000)
    log.close()
    again = Log(tmp_path / "g.db")
    assert again.get_value("measurement_seq_reserved") == 20000
    assert again.get_value("nothing", 7) == 7
    again.close()


def test_an_old_log_gains_the_new_columns(tmp_path) -> None:
    db = sqlite3.connect(tmp_path / "g.db")
    db.executescript("""
        CREATE TABLE compensation_decisions (id INTEGER PRIMARY KEY AUTOINCREMENT,
            wall_time REAL NOT NULL, kind TEXT NOT NULL, reason TEXT NOT NULL,
            measurement_seq INTEGER, deviation_mm REAL, filtered_mm REAL, offset_mm REAL,
            offset_seq INTEGER, before_mm REAL NOT NULL, after_mm REAL NOT NULL,
            shadow INTEGER NOT NULL);
        INSERT INTO compensation_decisions (wall_time, kind, reason, before_mm, after_mm,
            shadow) VALUES (1.8e9, 'applied', 'old row', 0, 0.001, 0);""")
    db.close()
    log = Log(tmp_path / "g.db")
    [row] = log.decisions()
    assert row["reason"] == "old row" and row["count"] == 1 and row["last_time"] == 1.8e9
    log.close()


def test_a_full_disk_keeps_the_rows_and_writes_them_later(tmp_path, small_disk) -> None:  # noqa: F811
    log = Log(small_disk.path / "g.db")
    st = ControllerState()
    small_disk.fill()
    fut = log.submit(Decision(Kind.WRITE, "write", 0.0, offset_seq=1, code="write"),
                     time.time(), st, durable=True)
    with pytest.raises(sqlite3.Error):
        fut.result(10)
    assert "cannot be written" in log.problem
    for _ in range(50):
        log.submit(held(), time.time(), st)
    small_disk.free()
    deadline = time.monotonic() + 10
    while log.problem and time.monotonic() < deadline:
        time.sleep(0.1)
    assert log.problem == ""
    assert log.flush(30.0)
    kinds = [(r["kind"], r["count"]) for r in reversed(log.decisions(limit=10))]
    assert kinds == [("write", 1), ("held", 50)], kinds
    log.close()


def test_a_full_disk_drops_quiet_decisions_before_archived_rows_and_counts_the_rows(
        tmp_path, small_disk, monkeypatch) -> None:  # noqa: F811
    """The second outside probe: past the backlog, archived measurements were lost without a
    count. The oldest quiet decisions go first; archived rows only then, each counted."""
    import calib_store.compensation_log as module

    monkeypatch.setattr(module, "MAX_BACKLOG", 20)
    log = Log(small_disk.path / "g.db")
    st = ControllerState()
    small_disk.fill()
    row = {c: None for c in module.MEASUREMENT_COLUMNS}
    for i in range(15):
        log.submit(held(seq=i), time.time(), st)
        log.submit_measurement({**row, "seq": i, "wall_time": time.time(), "status": "ok"})
    deadline = time.monotonic() + 10
    while log.dropped < 10 and time.monotonic() < deadline:
        time.sleep(0.1)
    assert log.dropped == 10 and log.lost_measurements == 0  # the rows are kept
    for i in range(15, 30):
        log.submit_measurement({**row, "seq": i, "wall_time": time.time(), "status": "ok"})
    deadline = time.monotonic() + 10
    while log.lost_measurements < 10 and time.monotonic() < deadline:
        time.sleep(0.1)
    assert log.dropped == 15 and log.lost_measurements == 10, (log.dropped,
                                                               log.lost_measurements)
    small_disk.free()
    log.close()


def test_a_value_refused_on_a_full_disk_is_kept_only_when_it_is_a_reservation(
        tmp_path, small_disk) -> None:  # noqa: F811
    log = Log(small_disk.path / "g.db")
    log.put_value("settings", "before")
    small_disk.fill()
    change = log.submit_value("settings", "refused", retry=False)
    reservation = log.submit_value("reserved", 2000)
    for fut in (change, reservation):
        with pytest.raises(sqlite3.Error):
            fut.result(10)
    small_disk.free()
    deadline = time.monotonic() + 10
    while log.get_value("reserved") is None and time.monotonic() < deadline:
        time.sleep(0.1)
    assert log.get_value("reserved") == 2000  # written once there was room
    assert log.get_value("settings") == "before"  # its caller was told: never written
    log.close()
