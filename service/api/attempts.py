"""Wrong API keys counted per client address over a sliding window (time passed in): an
address past ``MAX_FAILURES`` within ``WINDOW_S`` is answered 429 (``service.api.auth``)."""

from __future__ import annotations

import collections
import threading

from service.config import ApiSettings

MAX_FAILURES = 20
WINDOW_S = 60.0


class KeyAttempts:
    """Wrong keys per client address over a sliding window (time passed in)."""

    def __init__(self, max_failures: int = MAX_FAILURES, window_s: float = WINDOW_S) -> None:
        self.max_failures, self.window_s = max_failures, window_s
        self._failures: dict[str, collections.deque[float]] = {}
        self._lock = threading.Lock()
        self.refused = 0  # wrong keys seen since the start

    def _recent(self, client: str, now: float) -> collections.deque[float]:
        times = self._failures.setdefault(client, collections.deque())
        while times and times[0] <= now - self.window_s:
            times.popleft()
        return times

    def retry_after(self, client: str, now: float) -> float:
        """Seconds until ``client`` may try a key again (0: now)."""
        with self._lock:
            times = self._recent(client, now)
            if len(times) < self.max_failures:
                return 0.0
            return times[-self.max_failures] + self.window_s - now

    def failed(self, client: str, now: float) -> int:
        """Count a wrong key from ``client``; how many it sent within the window."""
        with self._lock:
            times = self._recent(client, now)
            times.append(now)
            self.refused += 1
            if len(self._failures) > 10_000:  # a flood of addresses: forget the quiet ones
                for quiet in [c for c, t in self._failures.items() if not t][:5_000]:
                    del self._failures[quiet]
            return len(times)


_ATTEMPTS: dict[int, tuple[ApiSettings, KeyAttempts]] = {}


def attempts_for(api: ApiSettings) -> KeyAttempts:
    """The wrong-key counts of the API that ``api`` configures (one per settings object)."""
    entry = _ATTEMPTS.get(id(api))
    if entry is None or entry[0] is not api:
        entry = _ATTEMPTS[id(api)] = (api, KeyAttempts())
    return entry[1]
