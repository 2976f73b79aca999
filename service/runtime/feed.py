"""The measurements as they are published: the latest, the history, the fusion window, the
live subscribers, rate and latency, and the sequence numbers that never go back."""

from __future__ import annotations

import asyncio
import collections
import contextlib
import logging
import sqlite3
import statistics
import time
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np

from calib_store.compensation_log import CompensationLog
from drivers.camera.base import Frame
from service.measure.fuse import fuse
from service.measure.geometry import RigGeometry
from service.measure.result import Measurement
from service.measurement_record import MeasurementRecord
from service.runtime.listeners import Listeners

log = logging.getLogger("shaftgauge.feed")

SEQ_BLOCK = 10_000
"""Measurement sequence numbers are reserved in the store this many at a time: after a
restart the sequence goes on above every number used before (with a gap), never back."""
SEQ_KEY = "measurement_seq_reserved"


class Subscribers:
    """Live subscribers (SSE clients): one bounded queue each, oldest dropped when full."""

    def __init__(self, maxsize: int = 64) -> None:
        self._queues: set[asyncio.Queue] = set()
        self.maxsize = maxsize
        self.dropped = 0

    def add(self) -> asyncio.Queue:
        """A new subscriber's queue."""
        q: asyncio.Queue = asyncio.Queue(self.maxsize)
        self._queues.add(q)
        return q

    def remove(self, q: asyncio.Queue) -> None:
        """Forget a subscriber."""
        self._queues.discard(q)

    def publish(self, item: Any) -> None:
        """Give every subscriber the item; a full queue loses its oldest item."""
        for q in self._queues:
            if q.full():
                q.get_nowait()
                self.dropped += 1
            q.put_nowait(item)

    def __len__(self) -> int:
        return len(self._queues)


class SequenceCounter:
    """Measurement sequence numbers, above every number used before a restart.

    Parameters
    ----------
    store : CompensationLog or None
        Where the reservation lives (None: from ``floor``, not kept).
    floor : int
        The last number known to be used (the controller's last measurement).
    """

    def __init__(self, store: CompensationLog | None, floor: int = 0) -> None:
        self.store = store
        start = floor
        if store is not None:
            start = max(start, int(store.get_value(SEQ_KEY, 0)))
            try:
                store.put_value(SEQ_KEY, start + SEQ_BLOCK)
            except sqlite3.Error as err:  # a full disk: the block stays unreserved, say so
                log.error("measurement sequence not reserved (%s)", err)
        self.current = start
        self._reserved = start + SEQ_BLOCK

    def next(self) -> int:
        """The next number (reserving the next block in the store in good time)."""
        self.current += 1
        if self.store is not None and self.current >= self._reserved - SEQ_BLOCK // 2:
            self._reserved += SEQ_BLOCK
            with contextlib.suppress(sqlite3.Error):
                self.store.submit_value(SEQ_KEY, self._reserved)
        return self.current


class MeasurementFeed:
    """Owns what has been measured: the latest record (and its frame), the history ring
    buffer, the fusion window, live subscribers of measurements and of decisions, and the
    figures of rate and latency. Changed only on the event loop; read from anywhere."""

    def __init__(self, history: int, fuse_frames: int) -> None:
        self.latest: MeasurementRecord | None = None
        self.latest_frame: Frame | None = None
        # The latest measured frame with its measurement and the geometry it was measured with.
        self.latest_measured: tuple[Frame, Measurement, RigGeometry] | None = None
        # Plain tuples: the cyclic collector stops looking at a tuple of plain values (not at
        # a subclass of tuple), and a full history walked at every full pass stopped the
        # event loop for 40-90 ms.
        self._history: collections.deque[tuple] = collections.deque(maxlen=history)
        self.subscribers = Subscribers()
        self.decisions = Subscribers()
        # Set when the service stops: live streams end instead of holding the shutdown.
        self.closing = asyncio.Event()
        self._window: collections.deque[Measurement] = collections.deque(maxlen=fuse_frames)
        self._times: collections.deque[float] = collections.deque(maxlen=2000)
        self.latency_ms: collections.deque[float] = collections.deque(maxlen=2000)
        self.counters: collections.Counter[str] = collections.Counter()
        self._published: Listeners[MeasurementRecord] = Listeners("measurement published")

    def on_publish(self, listener: Callable[[MeasurementRecord], None]) -> None:
        """Call ``listener(record)`` for every record published (on the loop; keep it short:
        it is on the frame's path)."""
        self._published.add(listener)

    def fused(self, m: Measurement) -> Measurement | None:
        """Add a measurement to the fusion window; the fused value once it holds three."""
        self._window.append(m)
        return fuse(list(self._window)) if len(self._window) >= 3 else None

    def restart_fusion(self) -> None:
        """Forget the fusion window (a new calibration)."""
        self._window.clear()

    def publish(self, record: MeasurementRecord, m: Measurement, frame: Frame,
                geometry: RigGeometry) -> None:
        """Make ``record`` the latest and hand it to every subscriber."""
        self.latest_measured = (frame, m, geometry)
        self.latest = record
        self.counters["measured"] += 1
        self.counters["ok" if m else f"status_{m.status.value}"] += 1
        self._history.append(tuple(record))
        self._times.append(time.monotonic())
        self.latency_ms.append((time.monotonic_ns() - frame.received_ns) / 1e6)
        self.subscribers.publish(record)
        self._published.tell(record)

    def history_newest_first(self) -> Iterator[MeasurementRecord]:
        """The history's records, the newest first (from a copy: API threads read while the
        event loop appends)."""
        for values in reversed(list(self._history)):
            yield MeasurementRecord._make(values)

    def measurement_age_s(self) -> float | None:
        """Seconds since the latest measurement was published."""
        return None if not self._times else time.monotonic() - self._times[-1]

    def rate_hz(self, window_s: float = 10.0) -> float:
        """Measurements per second over the last ``window_s``."""
        now = time.monotonic()
        # A copy first (one C call, atomic under the GIL): API threads read while the event
        # loop appends, and iterating a deque that changes raises.
        recent = [t for t in list(self._times) if now - t <= window_s]
        if len(recent) < 2:
            return 0.0
        return (len(recent) - 1) / max(recent[-1] - recent[0], 1e-9)

    def latency_summary(self) -> dict[str, float | None]:
        """Median and 99th percentile of frame-to-registers latency, ms."""
        lat = list(self.latency_ms)
        if not lat:
            return {"median_ms": None, "p99_ms": None}
        return {"median_ms": statistics.median(lat),
                "p99_ms": float(np.percentile(lat, 99))}
