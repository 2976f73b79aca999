"""Waiting for a condition, never for a time.

A test waits until what it expects has happened and then asserts the outcome. The deadline
only ends a test whose behaviour is broken: it is generous enough for a two-core machine three
times slower than the development machine and loaded besides, so it never decides a pass.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Awaitable, Callable
from typing import TypeVar

T = TypeVar("T")

DEADLINE_S = 60.0
"""What a test waits at most for something that takes a second or two on a quiet machine."""


def until(predicate: Callable[[], T], what: str | Callable[[], str],
          timeout_s: float = DEADLINE_S, step_s: float = 0.1) -> T:
    """``predicate()``'s first true value; AssertionError naming ``what`` past the deadline
    (a callable: what it says then)."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            said = what() if callable(what) else what
            raise AssertionError(f"{said}: not within {timeout_s:g} s")
        time.sleep(step_s)


async def until_async(predicate: Callable[[], T | Awaitable[T]], what: str,
                      timeout_s: float = DEADLINE_S, step_s: float = 0.05) -> T:
    """As ``until`` on an event loop; ``predicate`` may be a coroutine function."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = predicate()
        if asyncio.iscoroutine(value) or isinstance(value, asyncio.Future):
            value = await value
        if value:
            return value  # type: ignore[return-value]
        if time.monotonic() > deadline:
            raise AssertionError(f"{what}: not within {timeout_s:g} s")
        await asyncio.sleep(step_s)
