"""What a measuring worker runs, a thread of the service or a process of its own.

A module outside ``service.runtime`` and importing only the core, so that a worker process
starts with what measuring needs and nothing of the service. ``time.monotonic_ns`` is the
machine's one monotonic clock, the same in every process.
"""

from __future__ import annotations

import os
import threading
import time

import numpy as np

from service.measure.compiled import compile_kernels
from service.measure.diameter import MeasureParams, measure_frame
from service.measure.geometry import RigGeometry
from service.measure.result import Measurement, Method

__all__ = ["measure_timed", "worker_start"]


def measure_timed(image: np.ndarray, origin: tuple[int, int] | None, geometry: RigGeometry,
                  method: Method, params: MeasureParams,
                  prior: tuple[np.ndarray, float] | None, near: np.ndarray | None,
                  scale_px: float | None) -> tuple[Measurement, int, int]:
    """``measure_frame(image, geometry, method, params, prior, near, origin, scale_px)``,
    and when it started and ended (``time.monotonic_ns``)."""
    t0 = time.monotonic_ns()
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
