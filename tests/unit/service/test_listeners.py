"""The one listener type: every listener told in order, one that raises logged and counted
while the others are still told."""

from __future__ import annotations

import logging

from service.runtime.listeners import Listeners


def test_a_listener_that_raises_does_not_silence_the_others(caplog) -> None:
    told: list[tuple[str, int]] = []
    decisions: Listeners[int] = Listeners("decision")
    decisions.add(lambda v: told.append(("registers", v)))
    decisions.add(lambda v: 1 / 0)
    decisions.add(lambda v: told.append(("opcua", v)))
    with caplog.at_level(logging.ERROR, "shaftgauge.listeners"):
        decisions.tell(7)
    assert told == [("registers", 7), ("opcua", 7)] and decisions.failures == 1
    assert "a listener of each decision failed" in caplog.text and len(decisions) == 3
