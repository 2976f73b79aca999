"""Type-1 gauge studies in the gauge's SQLite store: who ran one, on which calibration, the
values and the figures. Thread-safe (one lock); small and rare writes."""

from __future__ import annotations

import json
import threading
from pathlib import Path
from typing import Any

from calib_store.store import open_database, transaction

_COLUMNS = ("id", "started", "finished", "by", "calibration_id", "certified_mm",
            "tolerance_mm", "n", "state", "reason", "values", "result", "feature")


class GaugeStudyStore:
    """The studies, newest first.

    Parameters
    ----------
    path : str or Path
        The gauge's store file.
    """

    def __init__(self, path: str | Path) -> None:
        self._lock = threading.Lock()
        self._db = open_database(Path(path), True)
        with self._lock, transaction(self._db):  # a study cut short by a stop stays failed
            self._db.execute("UPDATE gauge_studies SET state = 'failed', reason = "
                             "'the service stopped during the study' WHERE state = 'running'")

    def start(self, started: float, by: str, calibration_id: int | None, certified_mm: float,
              tolerance_mm: float, n: int, feature: int | None = None) -> int:
        """A new running study (of a master of ``feature``, when named); its id."""
        with self._lock, transaction(self._db):
            cur = self._db.execute(
                "INSERT INTO gauge_studies (started, by, calibration_id, certified_mm, "
                "tolerance_mm, n, state, feature) VALUES (?, ?, ?, ?, ?, ?, 'running', ?)",
                (started, by, calibration_id, certified_mm, tolerance_mm, n, feature))
            return int(cur.lastrowid)

    def finish(self, study_id: int, finished: float, state: str, values: list[float],
               result: dict[str, Any] | None, reason: str = "") -> None:
        """Record the end of a study (``state``: ``done`` or ``failed``)."""
        with self._lock, transaction(self._db):
            self._db.execute(
                'UPDATE gauge_studies SET finished = ?, state = ?, reason = ?, "values" = ?, '
                "result = ? WHERE id = ?",
                (finished, state, reason, json.dumps(values),
                 None if result is None else json.dumps(result), study_id))

    def list(self, limit: int = 50) -> list[dict[str, Any]]:
        """The latest studies, newest first."""
        with self._lock:
            rows = self._db.execute(
                f"SELECT {', '.join(_quoted(c) for c in _COLUMNS)} FROM gauge_studies "
                "ORDER BY id DESC LIMIT ?", (limit,)).fetchall()
        return [_row(r) for r in rows]

    def latest_done(self) -> dict[str, Any] | None:
        """The latest study that finished with figures, or None."""
        with self._lock:
            row = self._db.execute(
                f"SELECT {', '.join(_quoted(c) for c in _COLUMNS)} FROM gauge_studies "
                "WHERE state = 'done' ORDER BY id DESC LIMIT 1").fetchone()
        return None if row is None else _row(row)

    def close(self) -> None:
        with self._lock:
            self._db.close()


def _quoted(c: str) -> str:
    return f'"{c}"'


def _row(r: tuple) -> dict[str, Any]:
    d = dict(zip(_COLUMNS, r, strict=True))
    d["values"] = json.loads(d["values"])
    d["result"] = None if d["result"] is None else json.loads(d["result"])
    return d



