"""Reading the measurement archive (the ``measurements`` table of the store): whole, a page at a
time, or what a file's header needs of it. The compensation log writes the rows from its own
thread; these read them on the log's reading connection, never waiting for the writer."""

from __future__ import annotations

import math
import sqlite3
import threading
from collections.abc import Iterator
from typing import Any

MEASUREMENT_COLUMNS = ("seq", "wall_time", "status", "diameter_mm", "uncertainty_mm",
                       "fused_diameter_mm", "deviation_mm", "in_tolerance", "calibration_id",
                       "nominal_mm", "tol_lower_mm", "tol_upper_mm", "tir_mm", "ront_mm",
                       "feature")


class ArchiveReading:
    """The archive's queries, for a class holding a reading connection (``_read``) and its
    lock (``_read_lock``): the compensation log."""

    _read: sqlite3.Connection
    _read_lock: threading.Lock

    def measurements(self, from_time: float | None = None, to_time: float | None = None,
                     limit: int = 1_000_000) -> list[dict[str, Any]]:
        """Archived measurements between two wall-clock times (Unix s, inclusive), oldest
        first."""
        lo = -math.inf if from_time is None else from_time
        hi = math.inf if to_time is None else to_time
        with self._read_lock:
            rows = self._read.execute(
                f"SELECT {', '.join(MEASUREMENT_COLUMNS)} FROM measurements WHERE wall_time "
                "BETWEEN ? AND ? ORDER BY seq LIMIT ?", (lo, hi, limit)).fetchall()
        return [dict(zip(MEASUREMENT_COLUMNS, r, strict=True)) for r in rows]

    def measurement_pages(self, from_time: float | None = None, to_time: float | None = None,
                          limit: int = 1_000_000, page: int = 5_000,
                          last_seq: int | None = None) -> Iterator[list[dict[str, Any]]]:
        """``measurements`` a page at a time (the first ``limit`` rows, oldest first, up to
        ``last_seq``: what a ``measurement_summary`` saw): the reader's lock is held for one
        page, never for the whole export, and no more than a page is in memory."""
        lo = -math.inf if from_time is None else from_time
        hi = math.inf if to_time is None else to_time
        top = 2**63 - 1 if last_seq is None else last_seq
        after, left = -1, limit
        while left > 0:
            with self._read_lock:
                rows = self._read.execute(
                    f"SELECT {', '.join(MEASUREMENT_COLUMNS)} FROM measurements WHERE "
                    "wall_time BETWEEN ? AND ? AND seq > ? AND seq <= ? ORDER BY seq LIMIT ?",
                    (lo, hi, after, top, min(page, left))).fetchall()
            if not rows:
                return
            yield [dict(zip(MEASUREMENT_COLUMNS, r, strict=True)) for r in rows]
            after, left = rows[-1][0], left - len(rows)

    def measurement_summary(self, from_time: float | None = None,
                            to_time: float | None = None, limit: int = 1_000_000
                            ) -> dict[str, Any]:
        """What a file's header needs of the first ``limit`` archived rows between two times,
        without reading them into memory: how many are good values (``good``), each feature
        the good ones were measured as (``features``, None first for rows of no feature: its
        number and ``judged``, the nominal and tolerance of its last row with a nominal, or
        None), whether any good one knew the run-out (``tir``) or the roundness (``ront``),
        and the last row's number (``last_seq``: the rows archived later are not the
        file's)."""
        lo = -math.inf if from_time is None else from_time
        hi = math.inf if to_time is None else to_time
        rows = ("SELECT * FROM measurements WHERE wall_time BETWEEN ? AND ? ORDER BY seq "
                "LIMIT ?")
        good = "status = 'ok' AND (fused_diameter_mm IS NOT NULL OR diameter_mm IS NOT NULL)"
        with self._read_lock:
            (last_seq,) = self._read.execute(f"SELECT MAX(seq) FROM ({rows})",
                                             (lo, hi, limit)).fetchone()
            last_seq = -1 if last_seq is None else int(last_seq)
            count, tir, ront = self._read.execute(
                f"SELECT COUNT(*), COUNT(tir_mm), COUNT(ront_mm) FROM ({rows}) WHERE {good} "
                "AND seq <= ?", (lo, hi, limit, last_seq)).fetchone()
            seen = [f for (f,) in self._read.execute(
                f"SELECT DISTINCT feature FROM ({rows}) WHERE {good} AND seq <= ? "
                "ORDER BY feature", (lo, hi, limit, last_seq))]  # NULL first
            # SQLite: a bare column beside MAX() is the maximal row's.
            judged = {f: dict(zip(("nominal_mm", "tol_lower_mm", "tol_upper_mm"), v,
                                  strict=True)) for f, *v, _ in self._read.execute(
                f"SELECT feature, nominal_mm, tol_lower_mm, tol_upper_mm, MAX(seq) FROM "
                f"({rows}) WHERE nominal_mm IS NOT NULL AND seq <= ? GROUP BY feature",
                (lo, hi, limit, last_seq))}
        return {"good": int(count), "tir": tir > 0, "ront": ront > 0, "last_seq": last_seq,
                "features": [{"feature": f, "judged": judged.get(f)} for f in seen]}

