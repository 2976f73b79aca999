"""The gauge store's schema and its life: one version, migrations in order, backups.

The store is one SQLite file shared by the calibrations (``store.py``), the decision log and
archive (``compensation_log.py``) and the gauge studies (``gauge_studies.py``). Its version is
SQLite's ``PRAGMA user_version``: 0 for a new file and for every file written before versions
existed (those are brought to version 1 by creating what they lack, which keeps every row).

Opening applies what is missing, in order, each migration in one transaction with the new
version, after a backup of the file beside it (``<file>.v<old>-<time>.bak``). A file of a
newer version than this release knows is refused: an older release must never run on a store
whose rules it does not know (a gauge study's gate, say).
"""

from __future__ import annotations

import json
import os
import re
import sqlite3
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path


class SchemaError(RuntimeError):
    """The store's schema cannot be used by this release; the message says why."""


_TABLES = [
    """CREATE TABLE IF NOT EXISTS calibrations (
        id INTEGER PRIMARY KEY AUTOINCREMENT,
        created REAL NOT NULL,
        created_by TEXT NOT NULL,
        note TEXT NOT NULL,
        document TEXT NOT NULL,
        quality TEXT)""",
    """CREATE TABLE IF NOT EXISTS active_calibration (
        id INTEGER PRIMARY KEY CHECK (id = 1),
        calibration_id INTEGER NOT NULL REFERENCES calibrations(id))""",
    """CREATE TABLE IF NOT EXISTS master_corrections (
        id INTEGER PRIMARY KEY AUTOINCREMENT,
        time REAL NOT NULL,
        calibration_id INTEGER NOT NULL REFERENCES calibrations(id),
        offset_mm REAL NOT NULL,
        scale REAL NOT NULL,
        masters TEXT NOT NULL,
        created_by TEXT NOT NULL)""",
    """CREATE TABLE IF NOT EXISTS master_checks (
        id INTEGER PRIMARY KEY AUTOINCREMENT,
        time REAL NOT NULL,
        calibration_id INTEGER,
        certified_mm REAL NOT NULL,
        measured_mm REAL NOT NULL,
        error_mm REAL NOT NULL,
        limit_mm REAL NOT NULL,
        passed INTEGER NOT NULL,
        created_by TEXT NOT NULL)""",
    """CREATE TABLE IF NOT EXISTS audit (
        id INTEGER PRIMARY KEY AUTOINCREMENT,
        time REAL NOT NULL,
        who TEXT NOT NULL,
        action TEXT NOT NULL,
        calibration_id INTEGER,
        detail TEXT NOT NULL)""",
    """CREATE TABLE IF NOT EXISTS compensation_decisions (
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
        shadow INTEGER NOT NULL)""",
    """CREATE TABLE IF NOT EXISTS compensation_state (
        id INTEGER PRIMARY KEY CHECK (id = 1),
        state TEXT NOT NULL)""",
    """CREATE TABLE IF NOT EXISTS measurements (
        seq INTEGER PRIMARY KEY,
        wall_time REAL NOT NULL,
        status TEXT NOT NULL,
        diameter_mm REAL,
        uncertainty_mm REAL,
        fused_diameter_mm REAL,
        deviation_mm REAL,
        in_tolerance INTEGER,
        calibration_id INTEGER,
        nominal_mm REAL,
        tol_lower_mm REAL,
        tol_upper_mm REAL)""",
    """CREATE TABLE IF NOT EXISTS gauge_values (
        key TEXT PRIMARY KEY,
        value TEXT NOT NULL)""",
    """CREATE TABLE IF NOT EXISTS gauge_studies (
        id INTEGER PRIMARY KEY AUTOINCREMENT,
        started REAL NOT NULL,
        finished REAL,
        by TEXT NOT NULL,
        calibration_id INTEGER,
        certified_mm REAL NOT NULL,
        tolerance_mm REAL NOT NULL,
        n INTEGER NOT NULL,
        state TEXT NOT NULL,
        reason TEXT NOT NULL DEFAULT '',
        "values" TEXT NOT NULL DEFAULT '[]',
        result TEXT)""",
]
# Columns the decision log gained before versions existed (older files lack them).
_DECISION_COLUMNS = {"code": "TEXT NOT NULL DEFAULT ''", "who": "TEXT NOT NULL DEFAULT ''",
                     "count": "INTEGER NOT NULL DEFAULT 1", "last_time": "REAL",
                     "last_measurement_seq": "INTEGER"}
_INDEXES = [
    "CREATE INDEX IF NOT EXISTS compensation_decisions_kind ON compensation_decisions "
    "(kind, id)",
    "CREATE INDEX IF NOT EXISTS compensation_decisions_last_time ON compensation_decisions "
    "(last_time)",
    "CREATE INDEX IF NOT EXISTS measurements_time ON measurements (wall_time)",
]


def _v1(db: sqlite3.Connection) -> None:
    for statement in _TABLES:
        db.execute(statement)
    have = {row[1] for row in db.execute("PRAGMA table_info(compensation_decisions)")}
    for column, decl in _DECISION_COLUMNS.items():
        if column not in have:
            db.execute(f"ALTER TABLE compensation_decisions ADD COLUMN {column} {decl}")
    db.execute("UPDATE compensation_decisions SET last_time = wall_time WHERE last_time IS NULL")
    for statement in _INDEXES:
        db.execute(statement)


def _v2(db: sqlite3.Connection) -> None:
    for column in ("tir_mm", "ront_mm"):
        db.execute(f"ALTER TABLE measurements ADD COLUMN {column} REAL")


_JOB_TABLES = [
    """CREATE TABLE jobs (
        id INTEGER PRIMARY KEY AUTOINCREMENT,
        part_number TEXT NOT NULL,
        version INTEGER NOT NULL,
        created REAL NOT NULL,
        created_by TEXT NOT NULL,
        note TEXT NOT NULL,
        document TEXT NOT NULL,
        UNIQUE (part_number, version))""",
    """CREATE TABLE active_job (
        id INTEGER PRIMARY KEY CHECK (id = 1),
        job_id INTEGER NOT NULL REFERENCES jobs(id))""",
    """CREATE TABLE job_audit (
        id INTEGER PRIMARY KEY AUTOINCREMENT,
        time REAL NOT NULL,
        who TEXT NOT NULL,
        action TEXT NOT NULL,
        job_id INTEGER,
        detail TEXT NOT NULL)""",
    """CREATE TABLE parts (
        id INTEGER PRIMARY KEY AUTOINCREMENT,
        serial TEXT NOT NULL,
        time REAL NOT NULL,
        job_id INTEGER REFERENCES jobs(id),
        verdict TEXT NOT NULL,
        features TEXT NOT NULL)""",
    "CREATE INDEX parts_time ON parts (time)",
    "CREATE INDEX parts_serial ON parts (serial)",
    "ALTER TABLE measurements ADD COLUMN feature INTEGER",
    "ALTER TABLE gauge_studies ADD COLUMN feature INTEGER",
]


def _v3(db: sqlite3.Connection) -> None:
    for statement in _JOB_TABLES:
        db.execute(statement)


def _v4(db: sqlite3.Connection) -> None:
    db.execute("ALTER TABLE compensation_decisions ADD COLUMN tool INTEGER")
    db.execute("""CREATE TABLE tool_states (
        tool INTEGER PRIMARY KEY,
        state TEXT NOT NULL)""")


def _single_tool(db: sqlite3.Connection) -> int:
    """The tool the single channel compensated: the active job's, when one tool finishes all
    its features; else tool 1 (the settings' single feature, ``Job.single``)."""
    row = db.execute("SELECT j.document FROM active_job a JOIN jobs j ON j.id = a.job_id"
                     ).fetchone()
    try:
        tools = {int(f["tool"]) for f in json.loads(row[0])["features"]} if row else set()
    except (ValueError, KeyError, TypeError):
        tools = set()
    return tools.pop() if len(tools) == 1 else 1


def _v5(db: sqlite3.Connection) -> None:
    db.execute("ALTER TABLE compensation_decisions ADD COLUMN entry INTEGER")
    db.execute("""CREATE TABLE entry_states (
        tool INTEGER NOT NULL,
        entry INTEGER NOT NULL,
        state TEXT NOT NULL,
        PRIMARY KEY (tool, entry))""")
    # The states as the release before kept them stay in their tables (no longer read).
    db.execute("INSERT INTO entry_states (tool, entry, state) "
               "SELECT tool, 0, state FROM tool_states")
    # The single channel's state and decisions are its tool's own entry's (a state of that
    # tool's channel in a job of several, if any, is the later: it stays).
    tool = _single_tool(db)
    db.execute("INSERT OR IGNORE INTO entry_states (tool, entry, state) "
               "SELECT ?, 0, state FROM compensation_state WHERE id = 1", (tool,))
    db.execute("UPDATE compensation_decisions SET tool = ? WHERE tool IS NULL", (tool,))


@dataclass(frozen=True)
class Migration:
    """One step of the schema: to ``version``, what it does, and how."""

    version: int
    what: str
    apply: Callable[[sqlite3.Connection], None]


MIGRATIONS = (
    Migration(1, "every table and column of the releases before versions (2026-11-22 to "
                 "2026-12-02), created where missing; the decision log's later columns added",
              _v1),
    Migration(2, "the measurement archive keeps the surface's run-out (TIR) and roundness "
                 "(RONt) where they were known, for the AQDEF export", _v2),
    Migration(3, "jobs (part programs: features and tools, versioned and audited), one record "
                 "per part, and the feature of each archived measurement and gauge study",
              _v3),
    Migration(4, "a compensation state per tool of a job of several tools, and the tool of "
                 "each decision (none: the single channel's, kept as before)", _v4),
    Migration(5, "one compensation state per offset entry (a tool and its offset number), "
                 "the single channel's becoming its tool's; the entry of each decision", _v5),
)
SCHEMA_VERSION = MIGRATIONS[-1].version


def version_of(db: sqlite3.Connection) -> int:
    """The file's schema version (0: new, or written before versions existed)."""
    return int(db.execute("PRAGMA user_version").fetchone()[0])


def pending(db: sqlite3.Connection, path: Path | str) -> list[Migration]:
    """The migrations this file still needs, in order.

    Raises
    ------
    SchemaError
        The file is of a newer schema than this release knows.
    """
    have = version_of(db)
    if have > SCHEMA_VERSION:
        raise SchemaError(
            f"store {path} has schema version {have}, written by a newer release; this "
            f"release knows versions up to {SCHEMA_VERSION}: run the release that wrote it, "
            "or restore a backup made before the upgrade")
    if have == 0:
        tables = {r[0] for r in db.execute(
            "SELECT name FROM sqlite_master WHERE type = 'table' AND name NOT LIKE 'sqlite_%'")}
        ours = {re.search(r"EXISTS (\w+)", t).group(1) for t in _TABLES}  # type: ignore[union-attr]
        if tables and not tables & ours:
            raise SchemaError(
                f"{path} is an SQLite database of something else (its tables: "
                f"{', '.join(sorted(tables)[:5])}{', ...' if len(tables) > 5 else ''}), not a "
                "shaftgauge store; it was left untouched: name the gauge's own store "
                "(store.path)")
    return [m for m in MIGRATIONS if m.version > have]


def backup(db: sqlite3.Connection, target: Path | str) -> Path:
    """A consistent copy of the open store at ``target`` (SQLite's online backup: writers may
    go on meanwhile). Refuses to overwrite a file."""
    target = Path(target)
    if target.exists():
        raise SchemaError(f"backup {target} exists already: name another file")
    target.parent.mkdir(parents=True, exist_ok=True)
    dest = sqlite3.connect(str(target))
    try:
        db.backup(dest)
    finally:
        dest.close()
    return target


def migrate(db: sqlite3.Connection, path: Path | str) -> list[Migration]:
    """Bring the open store up to ``SCHEMA_VERSION``: backed up first when it holds anything,
    then each pending migration in a transaction of its own with its version. Returns what
    was applied.

    Raises
    ------
    SchemaError
        A newer schema (nothing is changed), or a backup that cannot be written.
    """
    todo = pending(db, path)
    if not todo:
        return []
    old = version_of(db)
    tables = db.execute("SELECT COUNT(*) FROM sqlite_master WHERE type = 'table'").fetchone()[0]
    if tables and str(path) != ":memory:":
        stamp = time.strftime("%Y%m%dT%H%M%S", time.gmtime())
        name = f"{Path(path).name}.v{old}-{stamp}-{os.getpid()}.bak"
        backup(db, Path(path).with_name(name))
    for step in todo:
        db.execute("BEGIN IMMEDIATE")
        try:
            step.apply(db)
            db.execute(f"PRAGMA user_version = {int(step.version)}")
        except BaseException:
            db.execute("ROLLBACK")
            raise
        db.execute("COMMIT")
    return todo
