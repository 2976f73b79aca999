"""What a measuring worker runs, a thread of the service or a process of its own, and how a
frame reaches a process: through shared memory.

A module outside ``service.runtime`` and importing only the core, so that a worker process
starts with what measuring needs and nothing of the service. ``time.monotonic_ns`` is the
machine's one monotonic clock, the same in every process. A whole frame pickled through the
pool's pipe cost more than measuring it (at 100 frames/s of 1376x1024: 161 frames dropped in
30 s, the registers 82 ms late at the median); ``FrameSlots`` copies it once into a file in
``/dev/shm`` that the workers map.
"""

from __future__ import annotations

import contextlib
import mmap
import os
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from service.measure.compiled import compile_kernels
from service.measure.diameter import MeasureParams, measure_frame
from service.measure.geometry import RigGeometry
from service.measure.result import Measurement, Method

__all__ = ["FrameRef", "FrameSlots", "measure_timed", "worker_start"]

_PREFIX = "shaftgauge-frames-"


@dataclass(frozen=True)
class FrameRef:
    """Where a frame lies in a ``FrameSlots`` file."""

    path: str
    offset: int
    shape: tuple[int, ...]
    dtype: str
    slot: int


class FrameSlots:
    """Fixed slots of ``slot_bytes`` in a file under ``/dev/shm`` (else the temporary
    folder), mapped by the service and each worker: a frame is copied in once and read in
    place. Only the service's event loop puts and releases."""

    def __init__(self, slots: int, slot_bytes: int) -> None:
        folder = "/dev/shm" if os.path.isdir("/dev/shm") else tempfile.gettempdir()
        _remove_stale(Path(folder))
        fd, self.path = tempfile.mkstemp(prefix=f"{_PREFIX}{os.getpid()}-", dir=folder)
        try:
            os.ftruncate(fd, slots * slot_bytes)
            self._mm = mmap.mmap(fd, slots * slot_bytes)
        finally:
            os.close(fd)
        self.slot_bytes = slot_bytes
        self._free = list(range(slots))

    def put(self, image: np.ndarray) -> FrameRef | None:
        """The frame copied into a free slot; None when none is free or it is too large
        (the caller hands the frame itself)."""
        if image.nbytes > self.slot_bytes or not self._free:
            return None
        slot = self._free.pop()
        ref = FrameRef(self.path, slot * self.slot_bytes, tuple(image.shape), image.dtype.str,
                       slot)
        np.ndarray(image.shape, image.dtype, buffer=self._mm, offset=ref.offset)[...] = image
        return ref

    def release(self, ref: FrameRef | None) -> None:
        """The slot of a frame whose measurement is done (or lost) is free again."""
        if ref is not None and ref.path == self.path:
            self._free.append(ref.slot)

    def close(self) -> None:
        """Unmap and remove the file."""
        with contextlib.suppress(BufferError):
            self._mm.close()
        with contextlib.suppress(FileNotFoundError):
            os.unlink(self.path)


def _remove_stale(folder: Path) -> None:
    """Frame files left by services that were killed."""
    for f in folder.glob(f"{_PREFIX}*"):
        try:
            pid = int(f.name[len(_PREFIX):].split("-", 1)[0])
        except ValueError:
            continue
        if pid != os.getpid() and not Path(f"/proc/{pid}").exists():
            with contextlib.suppress(OSError):
                f.unlink()


_mapped: dict[str, mmap.mmap] = {}


def _frame(ref: FrameRef) -> np.ndarray:
    """The frame a reference names, read in place (the file mapped once per worker)."""
    mm = _mapped.get(ref.path)
    if mm is None:
        with open(ref.path, "r+b") as f:
            mm = mmap.mmap(f.fileno(), 0)
        _mapped[ref.path] = mm
    return np.ndarray(ref.shape, np.dtype(ref.dtype), buffer=mm, offset=ref.offset)


def measure_timed(image: np.ndarray | FrameRef, origin: tuple[int, int] | None,
                  geometry: RigGeometry,
                  method: Method, params: MeasureParams,
                  prior: tuple[np.ndarray, float] | None, near: np.ndarray | None,
                  scale_px: float | None) -> tuple[Measurement, int, int]:
    """``measure_frame(image, geometry, method, params, prior, near, origin, scale_px)``,
    and when it started and ended (``time.monotonic_ns``); ``image`` may be a ``FrameRef``
    into shared memory."""
    t0 = time.monotonic_ns()
    if isinstance(image, FrameRef):
        image = _frame(image)
    m = measure_frame(image, geometry, method, params, prior, near, origin, scale_px)
    return m, t0, time.monotonic_ns()


def worker_start(parent_pid: int, poll_s: float = 1.0) -> None:
    """A worker process's start: the compiled kernels loaded before its first frame, and a
    watch that ends it when the service is gone (killed -9, a worker would otherwise wait
    on its queue for ever: it holds the queue's other end itself)."""

    def watch() -> None:
        while os.getppid() == parent_pid:
            time.sleep(poll_s)
        os._exit(0)

    threading.Thread(target=watch, name="parent-watch", daemon=True).start()
    compile_kernels()
