"""Every compensation decision, and the controller's state, in SQLite: the cumulative offset
survives a restart, and the offset log can be read back (newest first)."""

from __future__ import annotations

import json
import threading
from dataclasses import asdict
from pathlib import Path
from typing import Any

from calib_store.store import open_database, transaction
from service.compensation import ControllerState, Decision

_SCHEMA = """
CREATE TABLE IF NOT EXISTS compensation_decisions (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    wall_time REAL NOT NULL,
    kind TEXT NOT NULL,
    reason TEXT NOT NULL,
    measurement_seq INTEGER,
    deviation_mm REAL,
    filtered_mm REAL,
    offset_mm REAL,
    offset_seq INTEGER,
    before_mm REAL NOT NULL,
    after_mm REAL NOT NULL,
    shadow INTEGER NOT NULL
);
CREATE TABLE IF NOT EXISTS compensation_state (
    id INTEGER PRIMARY KEY CHECK (id = 1),
    state TEXT NOT NULL
);
"""


class CompensationLog:
    """SQLite store of decisions and state. Thread-safe; one connection."""

    def __init__(self, path: str | Path, create_if_missing: bool = True) -> None:
        self.path = Path(path)
        self._lock = threading.Lock()
        self._db = open_database(self.path, create_if_missing)
        self._db.executescript(_SCHEMA)

    def record(self, decision: Decision, wall_time: float, state: ControllerState) -> None:
        """Store a decision and the state after it, in one transaction."""
        d = decision.as_dict()
        with self._lock, transaction(self._db):
            self._db.execute(
                "INSERT INTO compensation_decisions (wall_time, kind, reason, measurement_seq,"
                " deviation_mm, filtered_mm, offset_mm, offset_seq, before_mm, after_mm, shadow)"
                " VALUES (?,?,?,?,?,?,?,?,?,?,?)",
                (wall_time, d["kind"], d["reason"], d["measurement_seq"], d["deviation_mm"],
                 d["filtered_mm"], d["offset_mm"], d["offset_seq"], d["before_mm"],
                 d["after_mm"], int(d["shadow"])))
            self._db.execute("INSERT OR REPLACE INTO compensation_state (id, state) "
                             "VALUES (1, ?)", (json.dumps(asdict(state)),))

    def load_state(self) -> ControllerState:
        """The last saved state, or a fresh one."""
        with self._lock:
            row = self._db.execute("SELECT state FROM compensation_state WHERE id = 1"
                                   ).fetchone()
        return ControllerState(**json.loads(row[0])) if row else ControllerState()

    def decisions(self, limit: int = 100, before_id: int | None = None,
                  kinds: tuple[str, ...] | None = None) -> list[dict[str, Any]]:
        """Newest first, paged by id."""
        sql = "SELECT * FROM compensation_decisions WHERE 1=1"
        args: list[Any] = []
        if before_id is not None:
            sql += " AND id < ?"
            args.append(before_id)
        if kinds:
            sql += f" AND kind IN ({','.join('?' * len(kinds))})"
            args.extend(kinds)
        sql += " ORDER BY id DESC LIMIT ?"
        args.append(int(limit))
        with self._lock:
            cur = self._db.execute(sql, args)
            cols = [c[0] for c in cur.description]
            rows = cur.fetchall()
        out = [dict(zip(cols, r, strict=True)) for r in rows]
        for r in out:
            r["shadow"] = bool(r["shadow"])
        return out

    def close(self) -> None:
        """Close the database."""
        with self._lock:
            self._db.close()
