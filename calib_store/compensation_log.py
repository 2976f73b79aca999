"""Every compensation decision, the controller's state and the service's own durable values in
SQLite, written by one thread of its own (never on the event loop).

- A run of quiet decisions (held, refused, proposed) of one kind and code between two
  significant ones (a write, an outcome, an alarm, a reset, a settings change, ...) is one row
  with a ``count``, its first and last time and measurement, and the latest reason: "held: no
  nominal diameter set" ten times a second for a day is one row, not 860 000.
- Writes are batched: one transaction a batch, the controller's latest state with it. A
  decision submitted ``durable`` (an order to write an offset) is committed before its future
  resolves: an offset that cannot be logged is not written.
- Retention by age and by rows (``LogRetention``); indexed for the log's queries, which run on
  a connection of their own and never wait for the writer.
- A write that fails (a full disk) is kept and tried again every second; ``problem`` says
  why meanwhile.
"""

from __future__ import annotations

import concurrent.futures
import contextlib
import json
import logging
import queue
import sqlite3
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from calib_store.archive_reading import MEASUREMENT_COLUMNS, ArchiveReading
from calib_store.store import open_database, transaction

log = logging.getLogger("shaftgauge.compensation_log")

_COLUMNS = ("id", "wall_time", "last_time", "count", "kind", "code", "reason", "who",
            "measurement_seq", "last_measurement_seq", "deviation_mm", "filtered_mm",
            "offset_mm", "offset_seq", "before_mm", "after_mm", "shadow", "tool", "entry")
RETRY_S = 1.0
MAX_BACKLOG = 10_000


@dataclass(frozen=True)
class LogRetention:
    """How much of the decision log is kept: rows newer than ``max_age_days`` and at most
    ``max_rows`` of them (the oldest go first)."""

    max_age_days: float = 365.0
    max_rows: int = 1_000_000
    prune_every_s: float = 60.0
    max_measurements: int = 2_000_000
    """Archived measurements kept (the oldest go first)."""


@dataclass
class _Item:
    """One unit of work for the writer thread."""

    kind: str  # "decision", "value", "value_once", "measurement", "barrier"
    payload: Any
    future: concurrent.futures.Future | None


class CompensationLog(ArchiveReading):
    """The decision log, the controller's state and the service's durable values.

    Parameters
    ----------
    path : str or Path
        The SQLite file (shared with the calibration store).
    create_if_missing : bool
        Create the file when it is not there.
    retention : LogRetention
        What is kept.
    """

    def __init__(self, path: str | Path, create_if_missing: bool = True,
                 retention: LogRetention | None = None) -> None:
        self.path = Path(path)
        self.retention = retention or LogRetention()
        self._db = open_database(self.path, create_if_missing)  # its tables: schema.py
        self._read_lock = threading.Lock()
        self._read = sqlite3.connect(str(self.path), check_same_thread=False,
                                     isolation_level=None)
        self._queue: queue.Queue[_Item | None] = queue.Queue()
        self._backlog: list[_Item] = []   # items whose write failed, tried again
        self._open_runs: dict[tuple[str, str, bool, int | None, int | None], int] = {}
        self._last_prune = 0.0
        self.problem = ""                 # why the log cannot be written now ("" when it can)
        self.dropped = 0                  # quiet decisions dropped past MAX_BACKLOG
        self.lost_measurements = 0        # archived measurements dropped past it
        self.rows_written = 0
        self._closed = False
        self._thread = threading.Thread(target=self._run, name="compensation-log", daemon=True)
        self._thread.start()

    # ---- submitting ----------------------------------------------------------------------

    def submit(self, decision: dict[str, Any], wall_time: float, state: dict[str, Any],
               quiet: bool = False, durable: bool = False, tool: int = 1, entry: int = 0
               ) -> concurrent.futures.Future | None:
        """Queue a decision (a dict with the columns of ``_COLUMNS``: ``kind``, ``code``,
        ``reason``, ``who``, its figures) and the state after it (JSON-ready) of the
        controller of ``tool``'s offset ``entry`` (0: the tool's own). A ``quiet`` decision
        joins the open run of its kind, code and entry. With ``durable`` the returned future
        resolves once both are committed (or raises the ``sqlite3.Error`` that stopped it)."""
        fut: concurrent.futures.Future | None = concurrent.futures.Future() if durable else None
        # The state is serialised by the writer thread, once a batch (the last one counts).
        self._put(_Item("decision", (dict(decision, tool=int(tool), entry=int(entry)),
                                     wall_time, state, quiet), fut))
        return fut

    def record(self, decision: dict[str, Any], wall_time: float, state: dict[str, Any],
               quiet: bool = False, tool: int = 1, entry: int = 0) -> None:
        """Store a decision and the state after it, and wait until they are committed."""
        fut = self.submit(decision, wall_time, state, quiet, durable=True, tool=tool,
                          entry=entry)
        assert fut is not None
        fut.result()

    def submit_value(self, key: str, value: Any, retry: bool = True
                     ) -> concurrent.futures.Future:
        """Store a JSON-ready value under ``key``; the future resolves once it is committed.
        When it cannot be, the future fails and, with ``retry``, the value is written later
        (a reservation); without, never (a change the caller then did not make)."""
        fut: concurrent.futures.Future = concurrent.futures.Future()
        self._put(_Item("value" if retry else "value_once", (key, json.dumps(value)), fut))
        return fut

    def put_value(self, key: str, value: Any) -> None:
        """Store a JSON-ready value under ``key`` and wait until it is committed."""
        self.submit_value(key, value).result()

    def submit_measurement(self, row: dict[str, Any]) -> None:
        """Queue one measurement for the archive (a dict with ``MEASUREMENT_COLUMNS``)."""
        self._put(_Item("measurement", tuple(row.get(c) for c in MEASUREMENT_COLUMNS), None))

    def flush(self, timeout_s: float = 2.0) -> bool:
        """Wait until everything submitted so far is written (False: not within the time)."""
        fut: concurrent.futures.Future = concurrent.futures.Future()
        self._put(_Item("barrier", None, fut))
        try:
            fut.result(timeout_s)
            return True
        except (concurrent.futures.TimeoutError, sqlite3.Error):
            return False

    def _put(self, item: _Item) -> None:
        if self._closed:
            raise sqlite3.ProgrammingError("the compensation log is closed")
        self._queue.put(item)

    # ---- reading -------------------------------------------------------------------------

    def get_value(self, key: str, default: Any = None) -> Any:
        """The value stored under ``key``, or ``default``."""
        with self._read_lock:
            row = self._read.execute("SELECT value FROM gauge_values WHERE key = ?",
                                     (key,)).fetchone()
        return json.loads(row[0]) if row else default

    def load_state(self, tool: int = 1, entry: int = 0) -> dict[str, Any] | None:
        """The last saved state of the controller of ``tool``'s offset ``entry`` (0: the
        tool's own), or None."""
        with self._read_lock:
            row = self._read.execute("SELECT state FROM entry_states WHERE tool = ? AND "
                                     "entry = ?", (int(tool), int(entry))).fetchone()
        return json.loads(row[0]) if row else None

    def decisions(self, limit: int = 100, before_id: int | None = None,
                  kinds: tuple[str, ...] | None = None) -> list[dict[str, Any]]:
        """Newest first, paged by id. Each row is a decision, or a run of identical quiet
        ones (``count``, ``wall_time`` the first, ``last_time`` the last)."""
        self.flush(0.5)  # what was decided a moment ago, when the disk lets it be written
        sql = f"SELECT {', '.join(_COLUMNS)} FROM compensation_decisions WHERE 1=1"
        args: list[Any] = []
        if before_id is not None:
            sql += " AND id < ?"
            args.append(before_id)
        if kinds:
            sql += f" AND kind IN ({','.join('?' * len(kinds))})"
            args.extend(kinds)
        sql += " ORDER BY id DESC LIMIT ?"
        args.append(int(limit))
        with self._read_lock:
            rows = self._read.execute(sql, args).fetchall()
        out = [dict(zip(_COLUMNS, r, strict=True)) for r in rows]
        for r in out:
            r["shadow"] = bool(r["shadow"])
        return out

    def count_rows(self) -> int:
        """Rows in the decision log."""
        self.flush(0.5)
        with self._read_lock:
            return self._read.execute("SELECT COUNT(*) FROM compensation_decisions"
                                      ).fetchone()[0]

    def close(self) -> None:
        """Write what is queued (a few seconds at most), then close."""
        if self._closed:
            return
        self.flush(5.0)
        self._closed = True
        self._queue.put(None)
        self._thread.join(10.0)
        with self._read_lock:
            self._read.close()

    # ---- the writer thread ---------------------------------------------------------------

    def _run(self) -> None:
        while True:
            try:
                item = self._queue.get(timeout=RETRY_S if self._backlog else
                                       self.retention.prune_every_s)
            except queue.Empty:
                item = _Item("barrier", None, None)
            if item is None:
                break
            batch = [*self._backlog, item]
            self._backlog = []
            with contextlib.suppress(queue.Empty):
                while len(batch) < 2000:
                    nxt = self._queue.get_nowait()
                    if nxt is None:
                        self._queue.put(None)
                        break
                    batch.append(nxt)
            self._write(batch)
        with contextlib.suppress(sqlite3.Error):
            self._write(self._backlog) if self._backlog else None
        self._db.close()

    def _write(self, batch: list[_Item]) -> None:
        states: dict[tuple[int, int], dict[str, Any]] = {}  # the last of each entry's counts
        try:
            with transaction(self._db):
                runs = dict(self._open_runs)
                for item in batch:
                    if item.kind == "decision":
                        decision, wall_time, state, quiet = item.payload
                        states[decision["tool"], decision["entry"]] = state
                        self._insert(decision, wall_time, quiet, runs)
                    elif item.kind == "measurement":
                        self._db.execute(
                            f"INSERT OR REPLACE INTO measurements "
                            f"({', '.join(MEASUREMENT_COLUMNS)}) VALUES "
                            f"({','.join('?' * len(MEASUREMENT_COLUMNS))})", item.payload)
                    elif item.kind in ("value", "value_once"):
                        self._db.execute("INSERT OR REPLACE INTO gauge_values (key, value) "
                                         "VALUES (?, ?)", item.payload)
                for (tool, entry), state in states.items():
                    self._db.execute("INSERT OR REPLACE INTO entry_states (tool, entry, "
                                     "state) VALUES (?, ?, ?)", (tool, entry, json.dumps(state)))
                if self._prune() and runs:  # forget the runs whose rows were pruned
                    ids = list(runs.values())
                    alive = {r[0] for r in self._db.execute(
                        f"SELECT id FROM compensation_decisions WHERE id IN "
                        f"({','.join('?' * len(ids))})", ids)}
                    runs = {k: v for k, v in runs.items() if v in alive}
        except sqlite3.Error as err:
            if not self.problem:
                log.error("the compensation log cannot be written: %s", err)
            self.problem = f"the compensation log cannot be written ({err})"
            keep = []
            for item in batch:
                if item.future is not None and not item.future.done():
                    item.future.set_exception(err)
                if item.kind not in ("barrier", "value_once"):
                    keep.append(_Item(item.kind, item.payload, None))
            if len(keep) > MAX_BACKLOG:  # keep the significant ones: the oldest quiet
                # decisions go first, then the oldest archived measurements (counted)
                quiet = [i for i in keep if i.kind == "decision" and i.payload[3]]
                rows = [i for i in keep if i.kind == "measurement"]
                excess = (quiet + rows)[:len(keep) - MAX_BACKLOG]
                lost = sum(1 for i in excess if i.kind == "measurement")
                self.dropped += len(excess) - lost
                self.lost_measurements += lost
                drop = {id(i) for i in excess}
                keep = [i for i in keep if id(i) not in drop]
            self._backlog = keep
            return
        self._open_runs = runs
        if self.problem:
            log.info("the compensation log can be written again")
        self.problem = ""
        for item in batch:
            if item.future is not None and not item.future.done():
                item.future.set_result(None)

    def _insert(self, d: dict[str, Any], wall_time: float, quiet: bool,
                runs: dict[tuple[str, str, bool, int | None, int | None], int]) -> None:
        key = (d["kind"], d.get("code", ""), bool(d.get("shadow")), d.get("tool"),
               d.get("entry"))
        if quiet and key in runs:
            self._db.execute(
                "UPDATE compensation_decisions SET count = count + 1, last_time = ?, "
                "reason = ?, last_measurement_seq = ?, deviation_mm = ?, filtered_mm = ?, "
                "offset_mm = ?, before_mm = ?, after_mm = ? WHERE id = ?",
                (wall_time, d["reason"], d.get("measurement_seq"), d.get("deviation_mm"),
                 d.get("filtered_mm"), d.get("offset_mm"), d.get("before_mm", 0.0),
                 d.get("after_mm", 0.0), runs[key]))
            return
        cur = self._db.execute(
            "INSERT INTO compensation_decisions (wall_time, last_time, count, kind, code, "
            "reason, who, measurement_seq, last_measurement_seq, deviation_mm, filtered_mm, "
            "offset_mm, offset_seq, before_mm, after_mm, shadow, tool, entry) "
            "VALUES (?,?,1,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?)",
            (wall_time, wall_time, d["kind"], d.get("code", ""), d["reason"], d.get("who", ""),
             d.get("measurement_seq"), d.get("measurement_seq"), d.get("deviation_mm"),
             d.get("filtered_mm"), d.get("offset_mm"), d.get("offset_seq"),
             d.get("before_mm", 0.0), d.get("after_mm", 0.0), int(bool(d.get("shadow"))),
             d.get("tool"), d.get("entry")))
        self.rows_written += 1
        if quiet:
            runs[key] = int(cur.lastrowid)
        else:  # a significant decision ends every run
            runs.clear()

    def _prune(self) -> bool:
        """Apply the retention now and then; True when it ran (open runs may be gone)."""
        now = time.time()
        if now - self._last_prune < self.retention.prune_every_s:
            return False
        self._last_prune = now
        r = self.retention
        self._db.execute("DELETE FROM compensation_decisions WHERE last_time < ?",
                         (now - r.max_age_days * 86400.0,))
        self._db.execute("DELETE FROM compensation_decisions WHERE id <= (SELECT id FROM "
                         "compensation_decisions ORDER BY id DESC LIMIT 1 OFFSET ?)",
                         (r.max_rows,))
        self._db.execute("DELETE FROM measurements WHERE seq <= (SELECT seq FROM measurements "
                         "ORDER BY seq DESC LIMIT 1 OFFSET ?)", (r.max_measurements,))
        return True
