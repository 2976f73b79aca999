"""Messages kept for a broker that is away (store-and-forward), in SQLite: put in order, taken
out in order once the broker has acknowledged them, bounded (the oldest dropped and counted).

Synchronous: its owner calls it from one thread at a time (``service.plant.mqtt`` runs it on
a single-thread executor, so the event loop never waits on the disk).
"""

from __future__ import annotations

import sqlite3
from dataclasses import dataclass
from pathlib import Path

from calib_store.store import transaction

_SCHEMA = """
CREATE TABLE IF NOT EXISTS outbox (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    topic TEXT NOT NULL,
    payload BLOB NOT NULL,
    qos INTEGER NOT NULL,
    created REAL NOT NULL
);
CREATE TABLE IF NOT EXISTS outbox_counters (
    name TEXT PRIMARY KEY,
    value INTEGER NOT NULL
);
"""


@dataclass(frozen=True)
class OutboxMessage:
    """One message waiting for the broker."""

    id: int
    topic: str
    payload: bytes
    qos: int


class Outbox:
    """A bounded, durable FIFO of messages.

    Parameters
    ----------
    path : str or Path
        The SQLite file (``":memory:"``: kept in memory only).
    max_messages : int
        At most this many are kept; putting one more drops the oldest (``dropped`` counts
        them, across restarts).
    """

    def __init__(self, path: str | Path, max_messages: int) -> None:
        self.path = Path(path)
        self.max_messages = max_messages
        if str(path) != ":memory:":
            self.path.parent.mkdir(parents=True, exist_ok=True)
        self._db = sqlite3.connect(str(path), check_same_thread=False, isolation_level=None)
        self._db.execute("PRAGMA journal_mode=WAL")
        self._db.executescript(_SCHEMA)
        self._count = int(self._db.execute("SELECT COUNT(*) FROM outbox").fetchone()[0])
        row = self._db.execute("SELECT value FROM outbox_counters WHERE name = 'dropped'"
                               ).fetchone()
        self.dropped = int(row[0]) if row else 0
        """Messages dropped past the bound, since the file was made."""
        row = self._db.execute("SELECT value FROM outbox_counters WHERE name = 'last_number'"
                               ).fetchone()
        self.last_number = int(row[0]) if row else 0
        """The highest ``number`` put so far (kept across restarts, sent or not)."""

    def put(self, topic: str, payload: bytes, qos: int, created: float,
            number: int | None = None) -> int:
        """Keep a message (``number``: its owner's sequence number, remembered as
        ``last_number``); returns how many older ones were dropped to make room."""
        with transaction(self._db):
            if number is not None:
                self._db.execute(
                    "INSERT INTO outbox_counters (name, value) VALUES ('last_number', ?) "
                    "ON CONFLICT(name) DO UPDATE SET value = max(value, excluded.value)",
                    (number,))
                self.last_number = max(self.last_number, number)
            self._db.execute("INSERT INTO outbox (topic, payload, qos, created) "
                             "VALUES (?, ?, ?, ?)", (topic, payload, qos, created))
            self._count += 1
            excess = self._count - self.max_messages
            if excess > 0:
                self._db.execute("DELETE FROM outbox WHERE id IN (SELECT id FROM outbox "
                                 "ORDER BY id LIMIT ?)", (excess,))
                self._db.execute(
                    "INSERT INTO outbox_counters (name, value) VALUES ('dropped', ?) "
                    "ON CONFLICT(name) DO UPDATE SET value = value + excluded.value",
                    (excess,))
                self._count = self.max_messages
                self.dropped += excess
        return max(excess, 0)

    def peek(self, n: int = 100) -> list[OutboxMessage]:
        """The oldest ``n`` messages, oldest first (still kept)."""
        rows = self._db.execute("SELECT id, topic, payload, qos FROM outbox ORDER BY id "
                                "LIMIT ?", (n,)).fetchall()
        return [OutboxMessage(int(i), t, bytes(p), int(q)) for i, t, p, q in rows]

    def remove(self, message_id: int) -> None:
        """Forget a delivered message."""
        with transaction(self._db):
            cur = self._db.execute("DELETE FROM outbox WHERE id = ?", (message_id,))
            self._count -= cur.rowcount

    def __len__(self) -> int:
        return self._count

    def close(self) -> None:
        """Close the file."""
        self._db.close()

