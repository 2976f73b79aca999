"""Wrong API keys counted per client address over a sliding window (time passed in): an
address past ``MAX_FAILURES`` within ``WINDOW_S`` is answered 429 (``service.api.auth``)."""

from __future__ import annotations

from service.config import ApiSettings
from service.failures import FailureWindow

MAX_FAILURES = 20
WINDOW_S = 60.0


class KeyAttempts(FailureWindow):
    """Wrong keys per client address."""

    def __init__(self, max_failures: int = MAX_FAILURES, window_s: float = WINDOW_S) -> None:
        super().__init__(max_failures, window_s)


_ATTEMPTS: dict[int, tuple[ApiSettings, KeyAttempts]] = {}


def attempts_for(api: ApiSettings) -> KeyAttempts:
    """The wrong-key counts of the API that ``api`` configures (one per settings object)."""
    entry = _ATTEMPTS.get(id(api))
    if entry is None or entry[0] is not api:
        entry = _ATTEMPTS[id(api)] = (api, KeyAttempts())
    return entry[1]
