"""Calibrations in SQLite: versioned, one active at a time, an audit log of every change.

Each version keeps the interchange document exactly (``shaftgauge.calibration/1``), who made
it, when, a note and its quality figures. Activation is one transaction. A file that is not a
healthy SQLite database, or a stored document that no longer validates, is reported with what
is wrong and left untouched: the store never replaces or repairs a database by itself.
"""

from __future__ import annotations

import contextlib
import json
import os
import sqlite3
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from calib_store import schema
from calib_store.model import Calibration, CalibrationError, parse_calibration


class StoreError(RuntimeError):
    """The store cannot be used; the message says which file and what is wrong."""


class NotStoredError(RuntimeError):
    """A change could not be written to the store, so it was not made (the API answers 503
    with this message)."""


@dataclass(frozen=True)
class CalibrationInfo:
    """A stored calibration's metadata."""

    id: int
    created: float
    created_by: str
    note: str
    active: bool
    quality: dict[str, Any] | None

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return {"id": self.id, "created": self.created, "created_by": self.created_by,
                "note": self.note, "active": self.active, "quality": self.quality}


def open_database(path: Path, create_if_missing: bool) -> sqlite3.Connection:
    """Open (or create) the service's SQLite file, refusing a missing or damaged one.

    Raises
    ------
    StoreError
        Missing (when not allowed to create), empty, not a database, or failing its
        integrity check.
    """
    if not path.exists():
        if not create_if_missing:
            raise StoreError(f"calibration store {path} is missing (store.create_if_missing is "
                             "off: restore the file from a backup, or allow a new store)")
        path.parent.mkdir(parents=True, exist_ok=True)
    elif path.stat().st_size == 0:
        # SQLite would take an empty file for a new database and write one into it: a store
        # truncated to nothing would lose its whole history without a word.
        raise StoreError(f"calibration store {path} is empty (0 bytes: a truncated file, not "
                         "a store); it was left untouched: restore it from a backup "
                         "('shaftgauge store restore'), or move it aside to start a new one")
    # SQLite says only "unable to open database file" when its journal cannot be created.
    for where in ((path,) if path.exists() else ()) + (path.parent,):
        if not os.access(where, os.W_OK):
            raise StoreError(f"calibration store {path} cannot be written: {where} is "
                             "read-only (a read-only mount, or its permissions); the gauge "
                             "needs to write the store and its journal beside it")
    try:
        db = sqlite3.connect(str(path), check_same_thread=False, isolation_level=None)
        check = db.execute("PRAGMA integrity_check").fetchone()
        if not check or check[0] != "ok":
            db.close()
            raise StoreError(f"calibration store {path} is damaged ({_integrity(check)}); "
                             "it was left untouched: restore it from a backup ('shaftgauge "
                             "store restore')")
        schema.pending(db, path)  # a newer or foreign file is refused before anything is written
        db.execute("PRAGMA journal_mode=WAL")
        db.execute("PRAGMA foreign_keys=ON")
        schema.migrate(db, path)
    except schema.SchemaError as err:
        db.close()
        raise StoreError(str(err)) from None
    except sqlite3.DatabaseError as err:
        raise StoreError(f"calibration store {path} cannot be used: {err}; it was left "
                         "untouched") from None
    return db


def _integrity(check: tuple | None, lines: int = 3) -> str:
    """The first of SQLite's integrity problems: its whole list can run to thousands of
    lines, which belongs in ``sqlite3 FILE 'PRAGMA integrity_check'``, not in a status."""
    if not check:
        return "the integrity check gave no answer"
    found = [ln for ln in str(check[0]).splitlines() if ln and not ln.startswith("***")]
    more = len(found) - lines
    return "integrity check: " + "; ".join(found[:lines]) + (
        f"; {more} more (sqlite3 FILE 'PRAGMA integrity_check' lists them)" if more > 0
        else "")


@contextlib.contextmanager
def transaction(db: sqlite3.Connection) -> Iterator[None]:
    """One write transaction on an autocommit connection (the caller holds its lock): all of
    it, or none of it."""
    db.execute("BEGIN IMMEDIATE")
    try:
        yield
    except BaseException:
        db.execute("ROLLBACK")
        raise
    db.execute("COMMIT")


class CalibrationStore:
    """The versioned calibration store. Thread-safe."""

    def __init__(self, path: str | Path, create_if_missing: bool = True) -> None:
        self.path = Path(path)
        self._lock = threading.Lock()
        self._db = open_database(self.path, create_if_missing)

    def close(self) -> None:
        """Close the database."""
        with self._lock:
            self._db.close()

    def _transaction(self) -> contextlib.AbstractContextManager[None]:
        return transaction(self._db)

    # ---- reading ---------------------------------------------------------------------------

    def _active_id(self) -> int | None:
        row = self._db.execute("SELECT calibration_id FROM active_calibration WHERE id = 1"
                               ).fetchone()
        return None if row is None else int(row[0])

    def _info(self, row: tuple, active_id: int | None) -> CalibrationInfo:
        cid, created, by, note, quality = row
        return CalibrationInfo(cid, created, by, note, cid == active_id,
                               json.loads(quality) if quality else None)

    def list(self) -> list[CalibrationInfo]:
        """Every version, newest first."""
        with self._lock:
            active = self._active_id()
            rows = self._db.execute("SELECT id, created, created_by, note, quality FROM "
                                    "calibrations ORDER BY id DESC").fetchall()
        return [self._info(r, active) for r in rows]

    def get(self, calibration_id: int) -> tuple[CalibrationInfo, Calibration]:
        """One version and its document.

        Raises
        ------
        KeyError
            No such version.
        StoreError
            The stored document no longer validates.
        """
        with self._lock:
            active = self._active_id()
            row = self._db.execute("SELECT id, created, created_by, note, quality, document "
                                   "FROM calibrations WHERE id = ?",
                                   (calibration_id,)).fetchone()
        if row is None:
            raise KeyError(calibration_id)
        try:
            calibration = parse_calibration(json.loads(row[5]))
        except (CalibrationError, json.JSONDecodeError) as err:
            raise StoreError(f"stored calibration {calibration_id} is damaged: {err}") from None
        return self._info(row[:5], active), calibration

    def active(self) -> tuple[CalibrationInfo, Calibration] | None:
        """The active version, or None when none was activated."""
        with self._lock:
            active = self._active_id()
        return None if active is None else self.get(active)

    def audit(self, limit: int = 100) -> list[dict[str, Any]]:
        """The audit log, newest first."""
        with self._lock:
            cur = self._db.execute("SELECT id, time, who, action, calibration_id, detail FROM "
                                   "audit ORDER BY id DESC LIMIT ?", (int(limit),))
            cols = [c[0] for c in cur.description]
            return [dict(zip(cols, r, strict=True)) for r in cur.fetchall()]

    # ---- changing ------------------------------------------------------------------------

    def _audit(self, who: str, action: str, calibration_id: int | None, detail: str) -> None:
        self._db.execute("INSERT INTO audit (time, who, action, calibration_id, detail) "
                         "VALUES (?, ?, ?, ?, ?)",
                         (time.time(), who, action, calibration_id, detail))

    def add(self, calibration: Calibration, by: str, note: str = "",
            quality: dict[str, Any] | None = None, activate: bool = False) -> int:
        """Store a new version (and activate it when asked), in one transaction."""
        document = json.dumps(calibration.to_document())
        with self._lock, self._transaction():
            cur = self._db.execute(
                "INSERT INTO calibrations (created, created_by, note, document, quality) "
                "VALUES (?, ?, ?, ?, ?)",
                (time.time(), by, note, document,
                 None if quality is None else json.dumps(quality)))
            cid = int(cur.lastrowid)
            self._audit(by, "import", cid, note)
            if activate:
                self._activate(cid, by)
        return cid

    def _activate(self, cid: int, by: str) -> None:
        previous = self._active_id()
        self._db.execute("INSERT OR REPLACE INTO active_calibration (id, calibration_id) "
                         "VALUES (1, ?)", (cid,))
        self._audit(by, "activate", cid, f"previously {previous}")

    # ---- mastering -----------------------------------------------------------------------

    def add_correction(self, calibration_id: int, offset_mm: float, scale: float,
                       masters: list[dict[str, Any]], by: str) -> int:
        """Store a diameter correction for a calibration (the newest one is in force)."""
        with self._lock, self._transaction():
            cur = self._db.execute(
                "INSERT INTO master_corrections (time, calibration_id, offset_mm, scale, "
                "masters, created_by) VALUES (?, ?, ?, ?, ?, ?)",
                (time.time(), calibration_id, offset_mm, scale, json.dumps(masters), by))
            self._audit(by, "master correction", calibration_id,
                        f"offset {offset_mm * 1000:+.2f} um, scale {scale:.6f}")
        return int(cur.lastrowid)

    def correction(self, calibration_id: int) -> dict[str, Any] | None:
        """The correction in force for a calibration, or None."""
        with self._lock:
            cur = self._db.execute(
                "SELECT id, time, offset_mm, scale, masters, created_by FROM master_corrections"
                " WHERE calibration_id = ? ORDER BY id DESC LIMIT 1", (calibration_id,))
            row = cur.fetchone()
        if row is None:
            return None
        return {"id": row[0], "time": row[1], "offset_mm": row[2], "scale": row[3],
                "masters": json.loads(row[4]), "created_by": row[5]}

    def add_master_check(self, calibration_id: int | None, certified_mm: float,
                         measured_mm: float, error_mm: float, limit_mm: float, passed: bool,
                         by: str) -> None:
        """Record a master check (audited)."""
        with self._lock, self._transaction():
            self._db.execute(
                "INSERT INTO master_checks (time, calibration_id, certified_mm, measured_mm, "
                "error_mm, limit_mm, passed, created_by) VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
                (time.time(), calibration_id, certified_mm, measured_mm, error_mm, limit_mm,
                 int(passed), by))
            self._audit(by, "master check", calibration_id,
                        f"certified {certified_mm:.4f} mm, error {error_mm * 1000:+.2f} um, "
                        f"{'passed' if passed else 'failed'}")

    def last_master_check(self, calibration_id: int | None) -> dict[str, Any] | None:
        """The newest master check made with this calibration, or None (a check made with
        another calibration says nothing of this one)."""
        with self._lock:
            cur = self._db.execute("SELECT time, calibration_id, certified_mm, measured_mm, "
                                   "error_mm, limit_mm, passed, created_by FROM master_checks "
                                   "WHERE calibration_id IS ? ORDER BY id DESC LIMIT 1",
                                   (calibration_id,))
            cols = [c[0] for c in cur.description]
            row = cur.fetchone()
        if row is None:
            return None
        d = dict(zip(cols, row, strict=True))
        d["passed"] = bool(d["passed"])
        return d

    def activate(self, calibration_id: int, by: str) -> None:
        """Make a version the active one (atomic; audited).

        Raises
        ------
        KeyError
            No such version.
        StoreError
            Its document no longer validates (it is not activated).
        """
        self.get(calibration_id)  # exists and validates
        with self._lock, self._transaction():
            self._activate(calibration_id, by)
