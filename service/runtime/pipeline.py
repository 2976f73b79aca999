"""Frames to measurements: camera -> bounded queue -> worker pool -> results in frame order.

The camera's own thread fills a bounded drop-oldest queue; the intake task takes frames from
it and hands each to a pool of worker processes (or threads, ``processes``), at most
``workers`` in flight, each with the calibration in force when it was taken and the stripe
of the last frame measured (it is looked for there first:
``service.measure.stripe.extract_stripe``); the
publisher task hands the results on in frame order, and tells the camera where the stripe is
(its region of interest follows it: ``service.runtime.roi``). Nothing downstream can stall
acquisition."""

from __future__ import annotations

import asyncio
import collections
import contextlib
import logging
import multiprocessing
import os
import time
from collections.abc import Callable
from concurrent.futures import BrokenExecutor, Executor, ProcessPoolExecutor, ThreadPoolExecutor
from dataclasses import replace

import numpy as np

from drivers.camera.base import Camera, CameraError, Frame
from service.measure.cadence import ReflectionWatch
from service.measure.diameter import MeasureParams
from service.measure.result import Measurement, Method
from service.measure.runout_track import SpindleAngles
from service.measure_worker import FrameRef, FrameSlots, measure_timed, worker_start
from service.runtime.calibration import CalibrationContext, CalibrationInUse
from service.runtime.roi import KEEP, RegionFollower

log = logging.getLogger("shaftgauge.pipeline")

OnResult = Callable[[Frame, Measurement, CalibrationInUse], None]
FREE_FIT_HZ = 12.0
"""Free fits a second once the surface's position is settled, without the spindle's angle:
the axis moves over minutes."""
RUNOUT_FREE_FIT_HZ = 100.0
"""The same with the spindle's angle (every frame up to 100 frames a second): the run-out's
uncertainty shrinks with their number, and one costs a fortieth of a frame's measurement
(started from the frame's own circle)."""
SHARED_MIN_BYTES = 256 * 1024
"""Frames from this size on reach a worker process through shared memory; a smaller region
is pickled through the pool's pipe, which measured faster for it (a 170x347 region at 100
frames/s: p99 23 against 35 ms; a whole 1376x1024 frame: 2 against 161 frames dropped)."""


def frame_prior(frame_id: int, in_use: CalibrationInUse, angles: SpindleAngles | None
                ) -> tuple[tuple[np.ndarray, float] | None, tuple[float, bool] | None]:
    """Where a frame's circle is centred: the tracked spindle axis, or the surface's own
    centre at the frame's spindle angle once its run-out is known; and that angle with which
    of the two it is (None: no angle)."""
    prior = in_use.tracker.center() if in_use.tracker is not None else None
    if angles is None:
        return prior, None
    deg = angles.at(frame_id)
    if in_use.runout is None or prior is None:
        return prior, (deg, False)
    about = in_use.runout.prior_at(frame_id, deg, *prior)
    return (prior, (deg, False)) if about is None else (about, (deg, True))


class FramePipeline:
    """Owns the camera's frames until they are measured: the intake, the worker pool, the
    in-order publisher, the latest frame taken, and the pipeline's counters.

    Parameters
    ----------
    camera : Camera
        The frame source.
    context : CalibrationContext
        Which calibration a frame is measured with (read as the frame is taken).
    method, params : Method, MeasureParams
        How a frame is measured.
    workers : int
        Frames measured at once.
    on_result : callable
        ``on_result(frame, measurement, calibration_in_use)``, in frame order, on the loop.
    roi_margin_px : int or None
        The camera's region of interest follows the stripe with this margin; None reads the
        whole sensor.
    max_rate_hz : float or None
        At most this many frames a second are taken from the camera's queue (the rest are
        dropped there, oldest first, and counted); None takes them as fast as they are
        measured.
    reflection_check_hz : float
        Frames a second checked for a reflection beside the stripe while none is seen
        (``ReflectionWatch``).
    processes : bool
        Measure in worker processes instead of threads. A frame's measurement is mostly
        numpy calls on a few hundred values, which hold the interpreter's lock between them:
        in threads it contends with the event loop that publishes the results and answers
        the CNC (at 100 frames a second on two cores, frame -> registers p99 of 35-100 ms).
        A frame and its result cross a pipe (a tracked region of interest, tens of kB).
    """

    def __init__(self, camera: Camera, context: CalibrationContext, method: Method,
                 params: MeasureParams, workers: int, on_result: OnResult,
                 roi_margin_px: int | None = None, max_rate_hz: float | None = None,
                 reflection_check_hz: float = 5.0, processes: bool = False) -> None:
        self.camera, self.context = camera, context
        self.roi_margin_px = roi_margin_px
        self._min_interval_s = 0.0 if not max_rate_hz else 1.0 / max_rate_hz
        self._next_take = 0.0
        self._follower: RegionFollower | None = None
        self._whole_until = 0.0
        # The free circle (for the axis tracker and the surface's position) is fitted at most
        # FREE_FIT_HZ times a second once the position is settled (RUNOUT_FREE_FIT_HZ with the
        # spindle's angle: the run-out is fitted from them).
        self._free_fit_s = -1e9
        # A reflection is looked for a few times a second, and on every frame while one is
        # there (``ReflectionWatch``); the measurement itself checks every lopsided stripe.
        self.reflections = ReflectionWatch(reflection_check_hz)
        self._variants = {(free, check): replace(params, free_fit=free and params.free_fit,
                                                 reflection_check=check)
                          for free in (False, True) for check in (False, True)}
        self.method, self.params, self.workers = method, params, workers
        self.on_result = on_result
        # Told each frame's time waiting for a worker and measuring (on the loop).
        self.stage_listener: Callable[[str, float], None] | None = None
        self.latest_frame: Frame | None = None
        self.counters: collections.Counter[str] = collections.Counter()
        self.processes = processes
        self._pool = self._new_pool()
        # Frames reach worker processes through shared memory (made at the first frame, a
        # whole sensor's worth a slot).
        self._slots_shm: FrameSlots | None = None
        self._intake_pool = ThreadPoolExecutor(1, thread_name_prefix="intake")
        self._slots: asyncio.Semaphore | None = None
        self._in_flight: asyncio.Queue | None = None
        self._running = False
        # The stripe's centres in the last frame measured (px), None after a failure, and
        # the filters' scale it was found with (a wide stripe is extracted once at it).
        self._near: np.ndarray | None = None
        self._scale_px: float | None = None

    def _new_pool(self) -> Executor:
        if not self.processes:
            return ThreadPoolExecutor(self.workers, thread_name_prefix="measure")
        # Spawned, not forked: the service's threads (camera, loop) must not be copied
        # half-way through what they hold.
        return ProcessPoolExecutor(self.workers, mp_context=multiprocessing.get_context("spawn"),
                                   initializer=worker_start, initargs=(os.getpid(),))

    def _shared(self, frame: Frame, in_use: CalibrationInUse) -> FrameRef | None:
        """The frame in shared memory for a worker process (None: in threads, a region small
        enough to pickle, or no slot free)."""
        if not self.processes or frame.image.nbytes < SHARED_MIN_BYTES:
            return None
        if self._slots_shm is None:
            w, h = in_use.geometry.image_size
            self._slots_shm = FrameSlots(self.workers + 2,
                                         max(w * h * frame.image.itemsize, frame.image.nbytes))
        return self._slots_shm.put(frame.image)

    def _release(self, ref: FrameRef | None) -> None:
        if self._slots_shm is not None and ref is not None:
            self._slots_shm.release(ref)

    def _renew_pool(self, broken: Executor, err: BaseException) -> None:
        """A worker process died (killed, out of memory): its pool takes no more frames, so
        a new one takes over (once per broken pool); the frames in flight are lost and
        counted."""
        if broken is not self._pool:
            return
        log.error("a measuring worker process died (%s): starting new workers", err)
        self.counters["worker_restarts"] += 1
        self._pool = self._new_pool()
        broken.shutdown(wait=False, cancel_futures=True)

    def image_size(self) -> tuple[int, int] | None:
        """(width, height) of the camera's whole frames: the latest whole frame's, else the
        active calibration's (None when neither is known)."""
        frame = self.latest_frame
        if frame is not None and frame.origin is None:
            return frame.image.shape[1], frame.image.shape[0]
        if self.context.geometry is not None:
            return self.context.geometry.image_size
        return None

    def read_whole_sensor(self, hold_s: float) -> None:
        """Read the whole sensor for ``hold_s`` (a calibration capture wants whole frames):
        the region of interest stops following the stripe meanwhile."""
        self._whole_until = time.monotonic() + hold_s
        if self._follower is not None:
            self._follower.requested = None
        # A camera without regions reads the whole sensor anyway.
        with contextlib.suppress(CameraError):
            self.camera.set_region(None)

    def start(self) -> list[asyncio.Task]:
        """Start the camera; returns the intake and publisher tasks."""
        self._running = True
        self._slots = asyncio.Semaphore(self.workers)
        self._in_flight = asyncio.Queue()
        self.camera.start()
        loop = asyncio.get_running_loop()
        return [loop.create_task(self._intake(), name="intake"),
                loop.create_task(self._publisher(), name="publisher")]

    async def stop(self) -> None:
        """Stop the camera and the pools (the tasks are cancelled by their owner)."""
        self._running = False
        await asyncio.get_running_loop().run_in_executor(None, self.camera.stop)
        self._pool.shutdown(wait=True, cancel_futures=True)
        self._intake_pool.shutdown(wait=True, cancel_futures=True)
        if self._slots_shm is not None:
            self._slots_shm.close()

    def _params_now(self, in_use: CalibrationInUse, angled: bool = False) -> MeasureParams:
        """The settings for the next frame: with the free fit (every frame until the
        surface's position is settled, then when due: more often for a frame with a spindle
        angle, ``angled``) and the reflection check when due."""
        now = time.monotonic()
        hz = RUNOUT_FREE_FIT_HZ if angled else FREE_FIT_HZ
        free = self.params.free_fit and (not in_use.settling.settled
                                         or now - self._free_fit_s >= 1.0 / hz)
        if free:
            self._free_fit_s = now
        return self._variants[(free, self.reflections.due(now))]

    def _follow_stripe(self, frame: Frame, m: Measurement, in_use: CalibrationInUse) -> None:
        """Tell the camera where to read next (its region of interest follows the stripe)."""
        sensor = in_use.geometry.image_size
        if self._follower is None or self._follower.sensor != sensor:
            self._follower = RegionFollower(sensor, self.roi_margin_px or 32)
        region = None if frame.origin is None else (
            *frame.origin, frame.image.shape[1], frame.image.shape[0])
        points = m.stripe_px
        change = self._follower.update(points, region, time.monotonic())
        if change is KEEP:
            return
        try:
            self.camera.set_region(change)  # type: ignore[arg-type]
        except CameraError as err:  # a camera without regions: read the whole sensor
            log.warning("region of interest off: %s", err)
            self.roi_margin_px = None
            return
        self.counters["region_requests"] += 1

    async def _intake(self) -> None:
        """Frames from the camera to the worker pool, at most ``workers`` in flight."""
        loop = asyncio.get_running_loop()
        assert self._slots is not None and self._in_flight is not None
        while self._running:
            await self._slots.acquire()
            submitted = False
            try:
                if self._min_interval_s:  # the measuring rate's cap: wait for the next turn
                    await asyncio.sleep(max(0.0, self._next_take - loop.time()))
                    self._next_take = max(self._next_take, loop.time()) + self._min_interval_s
                frame = await loop.run_in_executor(self._intake_pool, self.camera.get_frame,
                                                   0.25)
                if frame is None:
                    continue
                self.counters["frames_in"] += 1
                self.latest_frame = frame
                in_use = self.context.in_use
                if in_use is None:
                    self.counters["frames_without_calibration"] += 1
                    continue
                prior, spindle = frame_prior(frame.frame_id, in_use, self.context.spindle)
                params = self._params_now(in_use, spindle is not None)
                pool, ref = self._pool, self._shared(frame, in_use)
                try:
                    fut = loop.run_in_executor(pool, measure_timed,
                                               frame.image if ref is None else ref,
                                               frame.origin, in_use.geometry, self.method,
                                               params, prior, self._near, self._scale_px)
                except BrokenExecutor as err:
                    self._release(ref)
                    self.counters["errors"] += 1
                    self._renew_pool(pool, err)
                    continue
                await self._in_flight.put((frame, in_use, fut, params.reflection_check, pool,
                                           ref, spindle))
                submitted = True
            except asyncio.CancelledError:
                raise
            except Exception:  # never let the pipeline die silently
                self.counters["errors"] += 1
                log.exception("pipeline intake error")
                await asyncio.sleep(0.1)
            finally:
                if not submitted:
                    self._slots.release()

    async def _publisher(self) -> None:
        """Results in frame order, each as soon as it and those before it are done."""
        assert self._slots is not None and self._in_flight is not None
        while True:
            frame, in_use, fut, checked, pool, ref, spindle = await self._in_flight.get()
            try:
                try:
                    m, t0, t1 = await fut
                finally:
                    self._release(ref)
                if self.stage_listener is not None:
                    self.stage_listener("wait", (t0 - frame.received_ns) / 1e9)
                    self.stage_listener("measure", (t1 - t0) / 1e9)
            except asyncio.CancelledError:
                raise
            except BrokenExecutor as err:
                self.counters["frames_lost_with_a_worker"] += 1
                self._renew_pool(pool, err)
                continue
            except Exception:
                self.counters["errors"] += 1
                log.exception("measurement error")
                continue
            finally:
                self._slots.release()
            if spindle is not None:
                m = replace(m, spindle_deg=spindle[0], about_runout=spindle[1])
            self._near = m.stripe_px
            self._scale_px = m.filter_px if m.stripe_px is not None else None
            self.reflections.seen(checked, m.reflection_px is not None)
            if m.reflection_px is not None:
                self.counters["reflections_modelled"] += 1
            if self.roi_margin_px is not None and time.monotonic() > self._whole_until:
                self._follow_stripe(frame, m, in_use)
            try:
                self.on_result(frame, m, in_use)
            except Exception:
                self.counters["errors"] += 1
                log.exception("publishing error")
