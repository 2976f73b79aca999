"""Frames handed to measuring worker processes through shared memory
(``service.measure_worker``)."""

from __future__ import annotations

import os

import numpy as np

from service import measure_worker as measuring
from service.measure_worker import FrameSlots


def test_a_frame_is_read_in_place_as_it_was_put() -> None:
    slots = FrameSlots(2, 64 * 48 * 2)
    try:
        a = np.arange(64 * 48, dtype=np.uint16).reshape(48, 64)
        b = (np.arange(32 * 20, dtype=np.uint8) % 251).reshape(20, 32)
        ra, rb = slots.put(a), slots.put(b)
        assert ra is not None and rb is not None and ra.slot != rb.slot
        assert slots.put(b) is None                   # no slot free: the caller sends the frame
        assert np.array_equal(measuring._frame(ra), a)
        assert np.array_equal(measuring._frame(rb), b)
        slots.release(ra)
        assert slots.put(np.zeros((49, 64), np.uint16)) is None  # larger than a slot
        again = slots.put(b[::2])                     # a strided view is copied whole
        assert again is not None and again.slot == ra.slot
        assert np.array_equal(measuring._frame(again), b[::2])
    finally:
        slots.close()
    assert not os.path.exists(slots.path)


def test_a_killed_services_frame_file_is_removed_by_the_next(tmp_path) -> None:
    stale = tmp_path / f"{measuring._PREFIX}999999999-abc"
    mine = tmp_path / f"{measuring._PREFIX}{os.getpid()}-abc"
    other = tmp_path / "unrelated"
    for f in (stale, mine, other):
        f.write_bytes(b"x")
    measuring._remove_stale(tmp_path)
    assert not stale.exists() and mine.exists() and other.exists()
