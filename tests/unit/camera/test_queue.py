"""The bounded hand-off: never blocks the producer, drops the oldest, counts drops."""

from __future__ import annotations

import threading
import time

import pytest

from drivers.camera.base import CameraConfig, CameraError
from drivers.camera.queue import DropOldestQueue


def test_drops_oldest_and_counts() -> None:
    q: DropOldestQueue[int] = DropOldestQueue(3)
    assert all(q.put(i) for i in range(3))
    assert q.put(3) is False and q.put(4) is False
    assert q.dropped == 2
    assert [q.get(0), q.get(0), q.get(0)] == [2, 3, 4]
    assert q.get(0.01) is None


def test_get_waits_for_a_producer() -> None:
    q: DropOldestQueue[str] = DropOldestQueue(1)
    threading.Timer(0.05, q.put, ("late",)).start()
    t0 = time.monotonic()
    assert q.get(2.0) == "late"
    assert time.monotonic() - t0 < 1.0


def test_close_wakes_waiters_and_reopen_restores() -> None:
    q: DropOldestQueue[int] = DropOldestQueue(2)
    out = []
    th = threading.Thread(target=lambda: out.append(q.get(None)))
    th.start()
    time.sleep(0.05)
    q.close()
    th.join(1.0)
    assert out == [None] and not th.is_alive()
    q.reopen()
    q.put(1)
    assert q.get(0.1) == 1


def test_a_fast_producer_is_never_blocked_by_a_slow_consumer() -> None:
    q: DropOldestQueue[int] = DropOldestQueue(4)
    t0 = time.monotonic()
    for i in range(100_000):
        q.put(i)
    assert time.monotonic() - t0 < 2.0
    assert len(q) == 4 and q.dropped == 100_000 - 4
    assert q.get(0) == 100_000 - 4


@pytest.mark.parametrize("kw", [{"pixel_format": "RGB8"}, {"trigger": "sometimes"},
                                {"n_buffers": 1}, {"queue_size": 0}])
def test_bad_camera_config_is_refused_with_reason(kw) -> None:
    with pytest.raises(CameraError, match=next(iter(kw)).split("_")[0]):
        CameraConfig(**kw)
