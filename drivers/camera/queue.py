"""A bounded frame hand-off that drops the oldest frame when the consumer is slow."""

from __future__ import annotations

import collections
import threading
from typing import Generic, TypeVar

T = TypeVar("T")


class DropOldestQueue(Generic[T]):
    """Thread-safe bounded queue: ``put`` never blocks, it drops the oldest item when full.

    The producer (an acquisition thread) must never wait for a slow consumer; the consumer
    always gets the freshest frames. Drops are counted.
    """

    def __init__(self, maxsize: int) -> None:
        if maxsize < 1:
            raise ValueError("maxsize must be >= 1")
        self._items: collections.deque[T] = collections.deque()
        self._maxsize = maxsize
        self._cond = threading.Condition()
        self._closed = False
        self.dropped = 0

    def put(self, item: T) -> bool:
        """Add an item; return False when an older item had to be dropped for it."""
        with self._cond:
            dropped = len(self._items) >= self._maxsize
            if dropped:
                self._items.popleft()
                self.dropped += 1
            self._items.append(item)
            self._cond.notify()
            return not dropped

    def get(self, timeout_s: float | None = None) -> T | None:
        """The oldest item, waiting up to ``timeout_s`` (forever when None); None on timeout
        or when the queue is closed and empty."""
        with self._cond:
            if not self._cond.wait_for(lambda: self._items or self._closed, timeout_s):
                return None
            return self._items.popleft() if self._items else None

    def close(self) -> None:
        """Wake every waiting consumer; later ``get`` calls return what is left, then None."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()

    def reopen(self) -> None:
        """Accept waiting again after ``close`` (a restarted camera)."""
        with self._cond:
            self._closed = False

    def clear(self) -> None:
        """Forget queued items."""
        with self._cond:
            self._items.clear()

    def __len__(self) -> int:
        with self._cond:
            return len(self._items)
