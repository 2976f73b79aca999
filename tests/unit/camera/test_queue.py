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
    # A consumer waiting without a timeout is woken by the put: without the wake-up it would
    # wait for ever (the join's deadline is only there to end a broken test).
    q: DropOldestQueue[str] = DropOldestQueue(1)
    out: list[str | None] = []
    th = threading.Thread(target=lambda: out.append(q.get(None)), daemon=True)
    th.start()
    threading.Timer(0.05, q.put, ("late",)).start()
    th.join(60.0)
    assert out == ["late"] and not th.is_alive()


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
    # The consumer takes one frame and then stalls until the producer is done: a put that
    # waited for room would never return (the join's deadline only ends a broken test).
    q: DropOldestQueue[int] = DropOldestQueue(4)
    taken, producer_done = [], threading.Event()

    def consume() -> None:
        taken.append(q.get(None))
        producer_done.wait(120.0)

    def produce() -> None:
        for i in range(1, 100_001):
            q.put(i)
        producer_done.set()

    consumer = threading.Thread(target=consume, daemon=True)
    consumer.start()
    q.put(0)
    while not taken:
        time.sleep(0.001)
    producer = threading.Thread(target=produce, daemon=True)
    producer.start()
    producer.join(60.0)
    assert not producer.is_alive(), f"put blocked: {len(q)} queued, {q.dropped} dropped"
    assert len(q) == 4 and q.dropped == 100_000 - 4
    assert q.get(0) == 100_000 - 3


@pytest.mark.parametrize("kw", [{"pixel_format": "RGB8"}, {"trigger": "sometimes"},
                                {"n_buffers": 1}, {"queue_size": 0}])
def test_bad_camera_config_is_refused_with_reason(kw) -> None:
    with pytest.raises(CameraError, match=next(iter(kw)).split("_")[0]):
        CameraConfig(**kw)
