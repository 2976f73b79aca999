"""Failures counted per client over a sliding window, with time passed in: wrong API keys
per address (``service.api.attempts``) and wrong OPC UA passwords per user name
(``service.plant.opcua``)."""

from __future__ import annotations

import collections
import threading


class FailureWindow:
    """Failures per client (an address, a user name) over a sliding window (time passed
    in): past ``max_failures`` within ``window_s`` the client waits."""

    def __init__(self, max_failures: int, window_s: float) -> None:
        self.max_failures, self.window_s = max_failures, window_s
        self._failures: dict[str, collections.deque[float]] = {}
        self._lock = threading.Lock()
        self.refused = 0  # failures seen since the start

    def _recent(self, client: str, now: float) -> collections.deque[float]:
        times = self._failures.setdefault(client, collections.deque())
        while times and times[0] <= now - self.window_s:
            times.popleft()
        return times

    def retry_after(self, client: str, now: float) -> float:
        """Seconds until ``client`` may try again (0: now)."""
        with self._lock:
            times = self._recent(client, now)
            if len(times) < self.max_failures:
                return 0.0
            return times[-self.max_failures] + self.window_s - now

    def failed(self, client: str, now: float) -> int:
        """Count a failure of ``client``; how many it had within the window."""
        with self._lock:
            times = self._recent(client, now)
            times.append(now)
            self.refused += 1
            if len(self._failures) > 10_000:  # a flood of addresses: forget the quiet ones
                for quiet in [c for c, t in self._failures.items() if not t][:5_000]:
                    del self._failures[quiet]
            return len(times)
