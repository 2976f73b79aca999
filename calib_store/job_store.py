"""Jobs and part records in the gauge's SQLite store.

A job (part program) is kept as versions: each change of a part number's job is a new row
with the next version, never an edit, and which one is active is audited with who changed
it. A part record is one finished part: its serial, time, job, each feature's fused
diameter, uncertainty and verdict, and the part's own verdict. The documents are checked by
the service (``service.compensation.job``) before they come here. Thread-safe (one lock).
"""

from __future__ import annotations

import json
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from calib_store.store import open_database, transaction


@dataclass(frozen=True)
class JobInfo:
    """One stored job version."""

    id: int
    part_number: str
    version: int
    created: float
    created_by: str
    note: str
    document: dict[str, Any]
    active: bool
    number: int = 0
    """The job's number: the same for every version of its part number (its first
    version's id), what a CNC writes to put the newest version in force."""

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return dict(self.__dict__)


_JOB = ("id, part_number, version, created, created_by, note, document, "
        "(SELECT MIN(j.id) FROM jobs AS j WHERE j.part_number = jobs.part_number)")
_PART = ("id", "serial", "time", "job_id", "verdict", "features")


class JobStore:
    """The jobs' versions, the active one, their audit, and the part records.

    Parameters
    ----------
    path : str or Path
        The gauge's store file.
    create_if_missing : bool
        As for the calibration store.
    """

    def __init__(self, path: str | Path, create_if_missing: bool = True) -> None:
        self._lock = threading.Lock()
        self._db = open_database(Path(path), create_if_missing)

    def close(self) -> None:
        """Close the file."""
        with self._lock:
            self._db.close()

    # ---- jobs ----------------------------------------------------------------------------

    def _info(self, row: tuple, active_id: int | None) -> JobInfo:
        return JobInfo(row[0], row[1], row[2], row[3], row[4], row[5], json.loads(row[6]),
                       row[0] == active_id, int(row[7]))

    def _active_id(self) -> int | None:
        row = self._db.execute("SELECT job_id FROM active_job WHERE id = 1").fetchone()
        return None if row is None else int(row[0])

    def add(self, document: dict[str, Any], by: str, note: str = "",
            activate: bool = False) -> int:
        """Store ``document`` as the next version of its part number's job (and make it the
        active job when asked), in one transaction; its id."""
        part_number = str(document["part_number"])
        with self._lock, transaction(self._db):
            latest = self._db.execute("SELECT MAX(version) FROM jobs WHERE part_number = ?",
                                      (part_number,)).fetchone()[0]
            version = 1 if latest is None else int(latest) + 1
            cur = self._db.execute(
                "INSERT INTO jobs (part_number, version, created, created_by, note, document) "
                "VALUES (?, ?, ?, ?, ?, ?)",
                (part_number, version, time.time(), by, note, json.dumps(document)))
            jid = int(cur.lastrowid)
            self._audit(by, "add", jid, f"{part_number} version {version}: {note}".rstrip(": "))
            if activate:
                self._activate(jid, by)
        return jid

    def activate(self, job_id: int, by: str) -> None:
        """Make ``job_id`` the active job (KeyError when there is none of that id)."""
        with self._lock, transaction(self._db):
            if self._db.execute("SELECT 1 FROM jobs WHERE id = ?", (job_id,)).fetchone() is None:
                raise KeyError(f"no job {job_id}")
            self._activate(job_id, by)

    def deactivate(self, by: str) -> None:
        """No stored job is in force any more."""
        with self._lock, transaction(self._db):
            previous = self._active_id()
            self._db.execute("DELETE FROM active_job")
            self._audit(by, "deactivate", previous, "")

    def _activate(self, job_id: int, by: str) -> None:
        previous = self._active_id()
        self._db.execute("INSERT OR REPLACE INTO active_job (id, job_id) VALUES (1, ?)",
                         (job_id,))
        self._audit(by, "activate", job_id, f"previously {previous}")

    def _audit(self, who: str, action: str, job_id: int | None, detail: str) -> None:
        self._db.execute("INSERT INTO job_audit (time, who, action, job_id, detail) VALUES "
                         "(?, ?, ?, ?, ?)", (time.time(), who, action, job_id, detail))

    def get(self, job_id: int) -> JobInfo:
        """One version (KeyError when there is none of that id)."""
        with self._lock:
            row = self._db.execute(f"SELECT {_JOB} FROM jobs WHERE id = ?",
                                   (job_id,)).fetchone()
            if row is None:
                raise KeyError(f"no job {job_id}")
            return self._info(row, self._active_id())

    def newest_of(self, number: int) -> JobInfo:
        """The newest version of the job numbered ``number`` (its first version's id;
        KeyError when no job has that number: a later version's id is none)."""
        with self._lock:
            row = self._db.execute(
                f"SELECT {_JOB} FROM jobs WHERE part_number = (SELECT part_number FROM jobs "
                "WHERE id = ? AND id = (SELECT MIN(j.id) FROM jobs AS j WHERE j.part_number "
                "= jobs.part_number)) ORDER BY version DESC LIMIT 1", (number,)).fetchone()
            if row is None:
                raise KeyError(f"no job numbered {number} (a job's number is its first "
                               "version's id, the same for every version)")
            return self._info(row, self._active_id())

    def active(self) -> JobInfo | None:
        """The active job, or None."""
        with self._lock:
            jid = self._active_id()
            if jid is None:
                return None
            row = self._db.execute(f"SELECT {_JOB} FROM jobs WHERE id = ?", (jid,)).fetchone()
            return self._info(row, jid)

    def list(self, limit: int = 200) -> list[JobInfo]:
        """The versions, newest first."""
        with self._lock:
            jid = self._active_id()
            rows = self._db.execute(f"SELECT {_JOB} FROM jobs ORDER BY id DESC LIMIT ?",
                                    (limit,)).fetchall()
            return [self._info(r, jid) for r in rows]

    def audit(self, limit: int = 100) -> list[dict[str, Any]]:
        """Who added and activated which job, newest first."""
        with self._lock:
            cur = self._db.execute("SELECT id, time, who, action, job_id, detail FROM job_audit "
                                   "ORDER BY id DESC LIMIT ?", (limit,))
            cols = [c[0] for c in cur.description]
            return [dict(zip(cols, r, strict=True)) for r in cur.fetchall()]

    # ---- parts ---------------------------------------------------------------------------

    def add_part(self, serial: str, when: float, job_id: int | None, verdict: str,
                 features: list[dict[str, Any]]) -> int:
        """Record one finished part; its id."""
        with self._lock, transaction(self._db):
            cur = self._db.execute(
                "INSERT INTO parts (serial, time, job_id, verdict, features) VALUES "
                "(?, ?, ?, ?, ?)", (serial, when, job_id, verdict, json.dumps(features)))
            return int(cur.lastrowid)

    def parts(self, limit: int = 100, before_id: int | None = None,
              serial: str | None = None, job_id: int | None = None) -> list[dict[str, Any]]:
        """Part records, newest first (those before ``before_id``; of one ``serial``; of one
        job)."""
        where, args = [], []
        if job_id is not None:
            where.append("job_id = ?")
            args.append(job_id)
        if before_id is not None:
            where.append("id < ?")
            args.append(before_id)
        if serial is not None:
            where.append("serial = ?")
            args.append(serial)
        sql = (f"SELECT {', '.join(_PART)} FROM parts"
               + (f" WHERE {' AND '.join(where)}" if where else "")
               + " ORDER BY id DESC LIMIT ?")
        with self._lock:
            rows = self._db.execute(sql, (*args, limit)).fetchall()
        out = [dict(zip(_PART, r, strict=True)) for r in rows]
        for r in out:
            r["features"] = json.loads(r["features"])
        return out
