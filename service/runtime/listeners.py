"""The one listener type of the running service.

A part that tells others what happened (a decision, a measurement published, a job changed,
another calibration) keeps a ``Listeners`` and offers ``on_<what>(listener)``; the
subscriptions themselves are made in one place, ``service.serve.wire``, never by a
constructor. A listener that raises is logged and the others are still told: a bug in the
OPC UA view must not keep a decision from the Modbus registers.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Generic, TypeVar

log = logging.getLogger("shaftgauge.listeners")
T = TypeVar("T")


class Listeners(Generic[T]):
    """Callables told each value in the order they were added.

    Parameters
    ----------
    what : str
        What they are told of, for the log ("decision", "measurement published").
    """

    def __init__(self, what: str) -> None:
        self.what = what
        self._listeners: list[Callable[[T], None]] = []
        self.failures = 0

    def add(self, listener: Callable[[T], None]) -> None:
        """Tell ``listener`` every value from now on."""
        self._listeners.append(listener)

    def tell(self, value: T) -> None:
        """Tell every listener ``value``; one that raises is logged and counted."""
        for listener in list(self._listeners):
            try:
                listener(value)
            except Exception:
                self.failures += 1
                log.exception("a listener of each %s failed", self.what)

    def __len__(self) -> int:
        return len(self._listeners)
