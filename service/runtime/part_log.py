"""The parts finished: the last ones for the API, counted by verdict, stored, and told to
whoever listens (the plant's links)."""

from __future__ import annotations

import logging
import sqlite3
from collections import deque
from collections.abc import Callable
from typing import Any

from calib_store.job_store import JobStore
from service.quality.parts import PartRecord
from service.runtime.listeners import Listeners

log = logging.getLogger("shaftgauge.jobs")

RECENT_PARTS = 50


class PartLog:
    """Owns the record of finished parts (``JobService`` hands it each as it finishes).

    Parameters
    ----------
    store : JobStore or None
        Where parts are kept (None: shown and counted, not stored).
    """

    def __init__(self, store: JobStore | None) -> None:
        self.store = store
        self.recent: deque[dict[str, Any]] = deque(maxlen=RECENT_PARTS)
        self.counts: dict[str, int] = {"ok": 0, "out": 0, "incomplete": 0}
        self._done: Listeners[dict[str, Any]] = Listeners("part finished")

    def on_part(self, listener: Callable[[dict[str, Any]], None]) -> None:
        """Call ``listener(part)`` (``PartRecord.as_dict``) for every finished part."""
        self._done.add(listener)

    def add(self, part: PartRecord, job_id: int | None) -> None:
        """A finished part of the stored job ``job_id`` (None: the settings' feature):
        recorded, counted, told, stored."""
        doc = part.as_dict()
        self.recent.appendleft(doc)
        self.counts[part.verdict] += 1
        self._done.tell(doc)
        if self.store is None:
            return
        try:
            self.store.add_part(part.serial, part.time_s, job_id, part.verdict,
                                [dict(f) for f in doc["features"]])
        except sqlite3.Error as err:  # a full disk: the part is still shown, and said
            log.error("part %s not stored: %s", part.serial, err)
