"""The running gauge: camera -> bounded queue -> worker pool -> subscribers.

The camera's own thread fills a bounded drop-oldest queue; an intake task takes frames from it
and hands each to a thread pool for measurement (numpy and OpenCV release the GIL), at most
``workers`` in flight, publishing results in frame order. Publishing updates the latest value,
the history ring buffer, the Modbus registers, the axis tracker, the fusion window and every
live subscriber, and queues the measurement for the compensation task. Nothing downstream can
stall acquisition: the camera queue and every subscriber queue drop their oldest item when full,
and count it.
"""

from __future__ import annotations

import asyncio
import collections
import contextlib
import json
import logging
import math
import sqlite3
import statistics
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np

from calib_store.compensation_log import CompensationLog
from calib_store.model import Calibration
from calib_store.store import CalibrationInfo, CalibrationStore
from drivers.camera.base import Camera, CameraState, Frame
from drivers.plc.client import OffsetWriter
from drivers.plc.registers import (
    Command,
    FaultBit,
    RegisterBank,
    StatusBit,
    mm_to_units,
    units_to_mm,
)
from drivers.plc.server import GaugeModbusServer, run_heartbeat
from service.calibrate.master import DiameterCorrection
from service.compensation import (
    CompensationController,
    CompensationSettings,
    ControllerState,
    Decision,
    MeasurementIn,
    State,
)
from service.config import Settings
from service.measure.axis_track import AxisTracker
from service.measure.diameter import MeasureParams, axis_center, measure_frame
from service.measure.fuse import fuse
from service.measure.geometry import RigGeometry, geometry_of
from service.measure.result import Measurement, Method
from service.measure.stripe import StripeParams
from service.measure.thermal import diameter_at_reference
from service.offsets import OffsetChannel

log = logging.getLogger("shaftgauge.service")


SEQ_BLOCK = 10_000
"""Measurement sequence numbers are reserved in the store this many at a time: after a
restart the sequence goes on above every number used before (with a gap), never back."""
RUNTIME_SETTINGS_KEY = "runtime_settings"
SEQ_KEY = "measurement_seq_reserved"


@dataclass(frozen=True)
class CalibrationInUse:
    """The calibration frames are measured with, and what belongs to it (its master
    correction, its axis tracker). A frame keeps the one it was taken under, even if another
    is activated while it is being measured."""

    info: CalibrationInfo
    calibration: Calibration
    geometry: RigGeometry
    correction: DiameterCorrection | None
    tracker: AxisTracker | None


@dataclass(frozen=True)
class MeasurementRecord:
    """One published measurement, as the API shows it (lengths in mm)."""

    seq: int
    time: float                 # wall clock, Unix seconds
    frame_id: int
    method: str
    status: str
    diameter_mm: float | None   # after the master correction
    raw_diameter_mm: float | None
    uncertainty_mm: float | None
    diameter_20c_mm: float | None
    fused_diameter_mm: float | None
    fused_uncertainty_mm: float | None
    deviation_mm: float | None  # from the nominal, when one is set
    in_tolerance: bool | None
    arc_deg: float
    n_points: int
    rms_residual_mm: float | None
    latency_ms: float           # frame received -> published
    reason: str
    note: str
    calibration_id: int | None = None  # the calibration it was measured with

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready: a non-finite number (a fit's NaN residual, say) becomes None."""
        return {k: finite_or_none(v) if isinstance(v, float) else v
                for k, v in asdict(self).items()}


class Subscribers:
    """Live subscribers (SSE clients): one bounded queue each, oldest dropped when full."""

    def __init__(self, maxsize: int = 64) -> None:
        self._queues: set[asyncio.Queue] = set()
        self.maxsize = maxsize
        self.dropped = 0

    def add(self) -> asyncio.Queue:
        """A new subscriber's queue."""
        q: asyncio.Queue = asyncio.Queue(self.maxsize)
        self._queues.add(q)
        return q

    def remove(self, q: asyncio.Queue) -> None:
        """Forget a subscriber."""
        self._queues.discard(q)

    def publish(self, item: Any) -> None:
        """Give every subscriber the item; a full queue loses its oldest item."""
        for q in self._queues:
            if q.full():
                q.get_nowait()
                self.dropped += 1
            q.put_nowait(item)

    def __len__(self) -> int:
        return len(self._queues)


class Gauge:
    """The whole measuring system in one process.

    Parameters
    ----------
    settings : Settings
        Validated settings.
    camera : Camera
        The frame source (Aravis or simulated).
    store : CalibrationStore or None
        The calibration store; None with ``store_error`` when it cannot be used.
    comp_log : CompensationLog or None
        Where decisions and controller state persist.
    writer : OffsetWriter or None
        The CNC's offset registers; None writes nothing.
    store_error : str
        Why there is no store.
    """

    def __init__(self, settings: Settings, camera: Camera, store: CalibrationStore | None,
                 comp_log: CompensationLog | None, writer: OffsetWriter | None,
                 store_error: str = "") -> None:
        self.settings = settings
        self.camera = camera
        self.store = store
        self.store_error = store_error
        self.comp_log = comp_log
        self.writer = writer
        self.bank = RegisterBank(settings.modbus.word_order)
        self.modbus = GaugeModbusServer(self.bank, settings.modbus.host, settings.modbus.port,
                                        settings.modbus.unit_id, on_write=self._on_register_write)
        state = ControllerState.from_dict(comp_log.load_state()) if comp_log else None
        comp_settings, self.part_temp_c, self.alpha_per_k = self._runtime_settings()
        controller = CompensationController(comp_settings, state or
                                            CompensationController().persisted)
        self.channel = OffsetChannel(controller, writer, comp_log, on_decision=self._on_decision)
        self.params = MeasureParams(stripe=StripeParams(
            optics_blur_px=settings.measurement.optics_blur_px),
            axis_sigma_mm=settings.measurement.axis_sigma_mm,
            free_fit=settings.measurement.track_axis,
            sheet_correction=settings.measurement.sheet_correction,
            sheet_sigma_mm=settings.measurement.sheet_sigma_mm)
        self.method = Method(settings.measurement.method)
        self.latest: MeasurementRecord | None = None
        self.latest_measurement: Measurement | None = None
        self.latest_frame: Frame | None = None
        # The latest measured frame with its measurement and the geometry it was measured with.
        self.latest_measured: tuple[Frame, Measurement, RigGeometry] | None = None
        self.history: collections.deque[MeasurementRecord] = collections.deque(
            maxlen=settings.measurement.history)
        self.subscribers = Subscribers()
        self.decisions = Subscribers()
        self.in_use: CalibrationInUse | None = None
        self._last_master_check: dict[str, Any] | None = None
        self._window: collections.deque[Measurement] = collections.deque(
            maxlen=settings.measurement.fuse_frames)
        self._seq, self._seq_reserved = self._reserve_sequence(controller)
        self.counters = collections.Counter()
        self._times: collections.deque[float] = collections.deque(maxlen=2000)
        self.latency_ms: collections.deque[float] = collections.deque(maxlen=2000)
        self._comp_queue: asyncio.Queue[MeasurementIn] | None = None
        self._slots: asyncio.Semaphore | None = None
        self._in_flight: asyncio.Queue | None = None
        self._tasks: list[asyncio.Task] = []
        self._command_tasks: set[asyncio.Task] = set()
        self._pool = ThreadPoolExecutor(settings.measurement.workers,
                                        thread_name_prefix="measure")
        self._intake_pool = ThreadPoolExecutor(1, thread_name_prefix="intake")
        self._running = False
        # (monotonic end, why, who set it, code) of an offset hold
        self._hold: tuple[float, str, str | None, str] | None = None
        self.started = time.time()
        if store is not None:
            try:
                active = store.active()
            except Exception as err:  # a damaged stored document: report, keep running
                self.store_error = str(err)
                active = None
            if active is not None:
                self.set_calibration(*active)
        self._feature_registers(comp_settings)
        self.bank.set("measurement_seq", self._seq & 0xFFFFFFFF)

    # ---- what survives a restart -------------------------------------------------------

    def _runtime_settings(self) -> tuple[CompensationSettings, float | None, float]:
        """The compensation settings and part temperature to start with: those last changed
        at run time, unless the config file's own have changed since (then the file's)."""
        s = self.settings
        from_file = _settings_doc(s.compensation, s.temperature.part_temp_c,
                                  s.temperature.alpha_per_k)
        stored = self.comp_log.get_value(RUNTIME_SETTINGS_KEY) if self.comp_log else None
        if stored is None or stored.get("config") != from_file:
            if stored is not None:
                log.warning("the config file's compensation or temperature settings changed "
                            "since the last run: they replace the changes made at run time")
            return s.compensation, s.temperature.part_temp_c, s.temperature.alpha_per_k
        known = CompensationSettings.__dataclass_fields__
        comp = CompensationSettings(**{k: v for k, v in stored["compensation"].items()
                                       if k in known})
        if comp.problems():
            log.error("stored runtime settings are inconsistent (%s): the config file's are "
                      "used", "; ".join(comp.problems()))
            return s.compensation, s.temperature.part_temp_c, s.temperature.alpha_per_k
        log.info("compensation settings as last changed at run time (shadow %s)", comp.shadow)
        return comp, stored["part_temp_c"], stored["alpha_per_k"]

    async def _save_runtime_settings(self) -> None:
        if self.comp_log is None:
            return
        s = self.settings
        doc = _settings_doc(self.channel.controller.settings, self.part_temp_c,
                            self.alpha_per_k)
        doc["config"] = _settings_doc(s.compensation, s.temperature.part_temp_c,
                                      s.temperature.alpha_per_k)
        try:
            await asyncio.wrap_future(self.comp_log.submit_value(RUNTIME_SETTINGS_KEY, doc))
        except sqlite3.Error as err:
            log.error("runtime settings not stored: %s", err)

    def _reserve_sequence(self, controller: CompensationController) -> tuple[int, int]:
        """(last used, reserved up to) for the measurement sequence: above every number used
        before, the next block reserved in the store before any is used."""
        start = controller.persisted.last_measurement_seq + 1
        if self.comp_log is None:
            return start, 1 << 62
        start = max(start, int(self.comp_log.get_value(SEQ_KEY, 0)))
        try:
            self.comp_log.put_value(SEQ_KEY, start + SEQ_BLOCK)
        except sqlite3.Error as err:  # a full disk: the block stays unreserved, say so
            log.error("measurement sequence not reserved (%s)", err)
        return start, start + SEQ_BLOCK

    def _next_seq(self) -> int:
        self._seq += 1
        if self.comp_log is not None and self._seq >= self._seq_reserved - SEQ_BLOCK // 2:
            self._seq_reserved += SEQ_BLOCK
            with contextlib.suppress(sqlite3.Error):
                self.comp_log.submit_value(SEQ_KEY, self._seq_reserved)
        return self._seq

    # ---- calibration -------------------------------------------------------------------

    @property
    def calibration(self) -> tuple[CalibrationInfo, Calibration] | None:
        """The active calibration and its info."""
        u = self.in_use
        return None if u is None else (u.info, u.calibration)

    @property
    def geometry(self) -> RigGeometry | None:
        """The active calibration's geometry."""
        return None if self.in_use is None else self.in_use.geometry

    @property
    def correction(self) -> DiameterCorrection | None:
        """The active calibration's master correction."""
        return None if self.in_use is None else self.in_use.correction

    @property
    def tracker(self) -> AxisTracker | None:
        """The active calibration's axis tracker."""
        return None if self.in_use is None else self.in_use.tracker

    def set_calibration(self, info: CalibrationInfo, calibration: Calibration) -> None:
        """Measure with this calibration from the next frame on; compensation takes only
        measurements made with it from now on."""
        geometry = geometry_of(calibration)
        corr = self.store.correction(info.id) if self.store is not None else None
        c0 = axis_center(geometry)
        tracker = (AxisTracker(c0, self.settings.measurement.axis_sigma_mm)
                   if c0 is not None and self.settings.measurement.track_axis else None)
        self.in_use = CalibrationInUse(info, calibration, geometry, None if corr is None else
                                       DiameterCorrection(corr["offset_mm"], corr["scale"],
                                                          corr["time"]), tracker)
        self._last_master_check = (self.store.last_master_check(info.id)
                                   if self.store is not None else None)
        self.channel.set_calibration(info.id)
        self._window.clear()
        log.info("calibration %d in use (%s)", info.id, info.note or "no note")

    def set_correction(self, correction: DiameterCorrection) -> None:
        """The active calibration's master correction, from the next frame on."""
        if self.in_use is None:
            raise RuntimeError("no active calibration")
        self.in_use = replace(self.in_use, correction=correction)

    def hold_offsets(self, seconds: float, why: str, owner: str | None = None,
                     code: str = "calibration") -> None:
        """Treat every measurement as doubtful for ``seconds`` from now (the camera is
        looking at a calibration board, or at the master): nothing is written to the CNC
        meanwhile. ``owner`` (a calibration session's id) may end it early with
        ``release_hold``; ``code`` names it in the decision log (``held_for_<code>``)."""
        self._hold = (time.monotonic() + seconds, why, owner, code)
        log.info("offsets held for %.0f s: %s", seconds, why)

    def release_hold(self, owner: str) -> bool:
        """End the hold if ``owner`` set it (a calibration session that has been activated).
        True when a hold ended."""
        if self.offset_hold() is None or self._hold[2] != owner:
            return False
        log.info("offsets no longer held (were: %s)", self._hold[1])
        self._hold = None
        return True

    def offset_hold(self) -> str | None:
        """Why offsets are held now, or None."""
        if self._hold is not None and time.monotonic() < self._hold[0]:
            return self._hold[1]
        return None

    # ---- life cycle --------------------------------------------------------------------

    async def start(self) -> None:
        """Start the camera, the Modbus server and the background tasks."""
        self._running = True
        self._comp_queue = asyncio.Queue(256)
        self._slots = asyncio.Semaphore(self.settings.measurement.workers)
        self._in_flight = asyncio.Queue()
        self.camera.start()
        if self.settings.modbus.enabled:
            await self.modbus.start()
        loop = asyncio.get_running_loop()
        self._tasks = [
            loop.create_task(self._intake(), name="intake"),
            loop.create_task(self._publisher(), name="publisher"),
            loop.create_task(self._compensate(), name="compensation"),
            loop.create_task(run_heartbeat(self.bank, self.healthy), name="heartbeat"),
            loop.create_task(self._refresh_registers(), name="registers"),
            loop.create_task(self.channel.run_settler(), name="settler"),
        ]

    async def stop(self) -> None:
        """Stop everything started by ``start``."""
        self._running = False
        for t in self._tasks:
            t.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)
        self._tasks = []
        await asyncio.get_running_loop().run_in_executor(None, self.camera.stop)
        await self.modbus.stop()
        if self.writer is not None:
            await self.writer.close()
        self._pool.shutdown(wait=True, cancel_futures=True)
        self._intake_pool.shutdown(wait=True, cancel_futures=True)
        if self.comp_log is not None:  # what was decided is on disk before the process ends
            await asyncio.to_thread(self.comp_log.flush, 5.0)

    # ---- the pipeline ------------------------------------------------------------------

    def _measure(self, frame: Frame, geometry: RigGeometry,
                 prior: tuple[np.ndarray, float] | None) -> Measurement:
        return measure_frame(frame.image, geometry, self.method, self.params, prior)

    async def _intake(self) -> None:
        """Frames from the camera to the worker pool, at most ``workers`` in flight."""
        loop = asyncio.get_running_loop()
        assert self._slots is not None and self._in_flight is not None
        while self._running:
            await self._slots.acquire()
            submitted = False
            try:
                frame = await loop.run_in_executor(self._intake_pool, self.camera.get_frame,
                                                   0.25)
                if frame is None:
                    continue
                self.counters["frames_in"] += 1
                self.latest_frame = frame
                in_use = self.in_use
                if in_use is None:
                    self.counters["frames_without_calibration"] += 1
                    continue
                prior = in_use.tracker.center() if in_use.tracker is not None else None
                fut = loop.run_in_executor(self._pool, self._measure, frame, in_use.geometry,
                                           prior)
                await self._in_flight.put((frame, in_use, fut))
                submitted = True
            except asyncio.CancelledError:
                raise
            except Exception:  # never let the pipeline die silently
                self.counters["pipeline_errors"] += 1
                log.exception("pipeline intake error")
                await asyncio.sleep(0.1)
            finally:
                if not submitted:
                    self._slots.release()

    async def _publisher(self) -> None:
        """Results in frame order, each as soon as it and those before it are done."""
        assert self._slots is not None and self._in_flight is not None
        while True:
            frame, in_use, fut = await self._in_flight.get()
            try:
                m = await fut
            except asyncio.CancelledError:
                raise
            except Exception:
                self.counters["pipeline_errors"] += 1
                log.exception("measurement error")
                continue
            finally:
                self._slots.release()
            try:
                self._publish(frame, m, in_use)
            except Exception:
                self.counters["pipeline_errors"] += 1
                log.exception("publishing error")

    def _publish(self, frame: Frame, m: Measurement, in_use: CalibrationInUse) -> None:
        self.latest_measured = (frame, m, in_use.geometry)
        raw_diameter = m.diameter_mm
        correction, tracker = in_use.correction, in_use.tracker
        if m and correction is not None:
            m = replace(m, diameter_mm=correction.apply(m.diameter_mm),
                        uncertainty_mm=None if m.uncertainty_mm is None
                        else m.uncertainty_mm * abs(correction.scale))
        seq = self._next_seq()
        now_ns = time.monotonic_ns()
        self.counters["measured"] += 1
        self.counters["ok" if m else f"status_{m.status.value}"] += 1
        if m and tracker is not None and m.free_center_mm and m.free_center_cov:
            xx, xy, yy = m.free_center_cov
            tracker.update(np.array(m.free_center_mm), np.array([[xx, xy], [xy, yy]]),
                                m.diameter_mm)
        self._window.append(m)
        fused = fuse(list(self._window)) if len(self._window) >= 3 else None
        d20 = None
        if m and self.part_temp_c is not None:
            d20 = diameter_at_reference(m.diameter_mm, self.part_temp_c, self.alpha_per_k)
        nominal = self.channel.controller.settings.nominal_mm
        dev = ((d20 if d20 is not None else m.diameter_mm) - nominal
               if m and nominal is not None else None)
        s = self.channel.controller.settings
        record = MeasurementRecord(
            seq=seq, time=time.time(), frame_id=frame.frame_id, method=m.method.value,
            status=m.status.value, diameter_mm=m.diameter_mm if m else None,
            raw_diameter_mm=raw_diameter if m else None,
            uncertainty_mm=m.uncertainty_mm if m else None, diameter_20c_mm=d20,
            fused_diameter_mm=fused.diameter_mm if fused else None,
            fused_uncertainty_mm=fused.uncertainty_mm if fused else None,
            deviation_mm=dev,
            in_tolerance=None if dev is None else bool(s.tol_lower_mm <= dev <= s.tol_upper_mm),
            arc_deg=float(m.arc_deg or 0.0), n_points=m.n_points,
            rms_residual_mm=m.rms_residual_mm, latency_ms=(now_ns - frame.received_ns) / 1e6,
            reason=m.reason, note=m.note, calibration_id=in_use.info.id)
        self.latest, self.latest_measurement = record, m
        self.history.append(record)
        self._times.append(time.monotonic())
        self.bank.set_many({
            "diameter": mm_to_units(record.diameter_mm),
            "uncertainty": mm_to_units(record.uncertainty_mm),
            "measurement_seq": seq & 0xFFFFFFFF,
            "measurement_age": 0,
        })
        self.latency_ms.append((time.monotonic_ns() - frame.received_ns) / 1e6)
        self.subscribers.publish(record)
        if self._comp_queue is not None:
            if self._comp_queue.full():
                self._comp_queue.get_nowait()
                self.counters["compensation_dropped"] += 1
            hold = self._hold if self.offset_hold() else None
            self._comp_queue.put_nowait(MeasurementIn(
                seq, frame.received_ns / 1e9,
                ("held_for_" + hold[3]) if hold else m.status.value,
                d20 if d20 is not None else m.diameter_mm, m.uncertainty_mm, in_use.info.id))

    async def _compensate(self) -> None:
        assert self._comp_queue is not None
        while True:
            m = await self._comp_queue.get()
            try:
                await self.channel.on_measurement(m)
            except asyncio.CancelledError:
                raise
            except Exception:
                self.counters["compensation_errors"] += 1
                log.exception("compensation error")

    def _on_decision(self, d: Decision) -> None:
        c = self.channel.controller
        update = {"cumulative_offset": mm_to_units(c.cumulative_mm),
                  "offset_seq": c.persisted.offset_seq & 0xFFFFFFFF}
        if d.offset_mm is not None:
            update["proposed_offset"] = mm_to_units(d.offset_mm)
        self.bank.set_many(update)
        self.decisions.publish(d)

    # ---- commands and settings ---------------------------------------------------------

    def _on_register_write(self, name: str, value: int) -> None:
        """A CNC wrote a register (called inside the Modbus server, on the event loop)."""
        if name == "command":
            self._spawn(self.run_command(Command(value), source="modbus"))
        elif name in ("nominal", "tol_upper", "tol_lower"):
            self._spawn(self._feature_from_cnc(name, value))

    def _spawn(self, coro) -> None:
        task = asyncio.get_running_loop().create_task(coro)
        self._command_tasks.add(task)
        task.add_done_callback(self._command_tasks.discard)

    async def _feature_from_cnc(self, name: str, value: int) -> None:
        s = self.channel.controller.settings
        changes = {"nominal": {"nominal_mm": units_to_mm(value)},
                   "tol_upper": {"tol_upper_mm": units_to_mm(value)},
                   "tol_lower": {"tol_lower_mm": units_to_mm(value)}}[name]
        try:
            await self.update_compensation(replace(s, **changes), who="modbus")
        except ValueError as err:  # consistent only once all three are written
            log.info("feature from the CNC not taken yet: %s", err)

    async def run_command(self, command: Command, source: str,
                          who: str | None = None) -> Decision | None:
        """Carry out a command (from the CNC or the API) and acknowledge it in the registers.

        A reset from the CNC's command register is refused (and logged) unless
        ``modbus.reset_command`` allows it; a reset moves the reference of the cumulative
        limit to where the CNC's total stands."""
        decision = None
        who = who or source
        if command is Command.RESET_COMPENSATION:
            if source == "modbus" and not self.settings.modbus.reset_command:
                decision = await self.channel.refuse_reset(
                    who, "resets from the CNC's command register are off "
                    "(modbus.reset_command); a technician resets over the API")
            else:
                decision = await self.channel.command("reset", who)
        elif command is Command.ACKNOWLEDGE_ALARM:
            decision = await self.channel.command("acknowledge", who)
        elif command is Command.MEASURE_NOW and self.camera.status().state is \
                CameraState.STREAMING:
            with contextlib.suppress(Exception):  # a free-running camera measures anyway
                self.camera.software_trigger()
        seq = (self.bank.get("command_seq") + 1) & 0xFFFF
        self.bank.set_many({"command": 0, "last_command": int(command), "command_seq": seq})
        log.info("command %s from %s", command.name.lower(), source)
        return decision

    async def update_compensation(self, settings: CompensationSettings, who: str) -> Decision:
        """New compensation settings (raises ValueError naming the bad setting), logged with
        who changed what and kept across restarts."""
        d = await self.channel.update_settings(settings, who)
        self._feature_registers(settings)
        await self._save_runtime_settings()
        return d

    async def set_temperature(self, part_temp_c: float | None, alpha_per_k: float | None,
                              who: str) -> None:
        """The part temperature (and expansion coefficient) for the diameter at 20 C; logged
        and kept across restarts."""
        self.part_temp_c = part_temp_c
        if alpha_per_k is not None:
            self.alpha_per_k = alpha_per_k
        await self.channel.note_settings(f"temperature changed (part_temp_c={part_temp_c!r}, "
                                         f"alpha_per_k={self.alpha_per_k!r})", who)
        await self._save_runtime_settings()

    def _feature_registers(self, settings: CompensationSettings) -> None:
        self.bank.set_many({"nominal": mm_to_units(settings.nominal_mm),
                            "tol_upper": mm_to_units(settings.tol_upper_mm),
                            "tol_lower": mm_to_units(settings.tol_lower_mm)})

    # ---- health and status -------------------------------------------------------------

    def measurement_age_s(self) -> float | None:
        """Seconds since the latest measurement was published."""
        return None if not self._times else time.monotonic() - self._times[-1]

    def healthy(self) -> bool:
        """Camera streaming, calibrated, and a fresh good measurement."""
        age = self.measurement_age_s()
        return bool(self._running and self.camera.status().state is CameraState.STREAMING
                    and self.geometry is not None and self.latest is not None
                    and self.latest.status == "ok" and age is not None
                    and age <= self.settings.measurement.max_age_s)

    def problems(self) -> list[str]:
        """What is wrong now, in words (empty when all is well)."""
        out = []
        cam = self.camera.status()
        if cam.state is not CameraState.STREAMING:
            out.append(f"camera {cam.state.value}: {cam.message}")
        if self.store_error:
            out.append(self.store_error)
        if self.geometry is None:
            out.append("no calibration is active: import and activate one")
        age = self.measurement_age_s()
        if self.geometry is not None and cam.state is CameraState.STREAMING:
            if age is None or age > self.settings.measurement.max_age_s:
                out.append("no recent measurement")
            elif self.latest is not None and self.latest.status != "ok":
                out.append(f"latest frame did not measure: {self.latest.reason}")
        if self.channel.log_problem:
            out.append(self.channel.log_problem + ": offsets are not written meanwhile")
        hold = self.offset_hold()
        if hold:
            out.append(f"offsets held: {hold}")
        if self.writer is not None and not self.writer.connected and \
                self.writer.outage_since is not None:
            out.append(f"CNC/PLC unreachable: {self.writer.last_error}")
        state = self.channel.controller.state
        if state in (State.ALARM, State.STOPPED, State.UNCERTAIN):
            out.append(f"compensation {state.value}")
        if self.channel.controller.writes_blocked:
            out.append(f"offsets blocked: {self.channel.controller.writes_blocked}")
        return out

    def rate_hz(self, window_s: float = 10.0) -> float:
        """Measurements per second over the last ``window_s``."""
        now = time.monotonic()
        # A copy first (one C call, atomic under the GIL): API threads read while the event
        # loop appends, and iterating a deque that changes raises.
        recent = [t for t in list(self._times) if now - t <= window_s]
        if len(recent) < 2:
            return 0.0
        return (len(recent) - 1) / max(recent[-1] - recent[0], 1e-9)

    def latency_summary(self) -> dict[str, float | None]:
        """Median and 99th percentile of frame-to-registers latency, ms."""
        lat = list(self.latency_ms)
        if not lat:
            return {"median_ms": None, "p99_ms": None}
        return {"median_ms": statistics.median(lat),
                "p99_ms": float(np.percentile(lat, 99))}

    def master_status(self) -> dict[str, Any]:
        """Correction in force, last master check, whether one is due, and whether offsets
        are blocked because of it."""
        last = self._last_master_check
        interval = self.settings.measurement.master_interval_h
        overdue = bool(interval is not None and (
            last is None or time.time() - last["time"] > interval * 3600.0))
        blocking = ""
        if last is not None and not last["passed"]:
            blocking = (f"the last master check failed ({last['error_mm'] * 1000:+.1f} um, "
                        f"limit {last['limit_mm'] * 1000:.1f} um)")
        elif overdue:
            blocking = f"a master check is overdue (every {interval:g} h)"
        corr = None if self.correction is None else asdict(self.correction)
        return {"correction": corr, "last_check": last, "overdue": overdue,
                "blocking": blocking or None}

    def record_master_check(self, certified_mm: float, measured_mm: float, error_mm: float,
                            limit_mm: float, passed: bool, by: str) -> None:
        """Store a master check and make it the one in force."""
        if self.store is None:
            raise RuntimeError(f"the calibration store cannot be used: {self.store_error}")
        cid = self.calibration[0].id if self.calibration else None
        self.store.add_master_check(cid, certified_mm, measured_mm, error_mm, limit_mm,
                                    passed, by)
        self._last_master_check = self.store.last_master_check(cid)

    async def _refresh_registers(self) -> None:
        while True:
            await asyncio.sleep(0.2)
            self.channel.set_writes_blocked(self.master_status()["blocking"] or "")
            self._set_status_registers()

    def _set_status_registers(self) -> None:
        status, faults = StatusBit(0), FaultBit(0)
        cam = self.camera.status()
        if self.healthy():
            status |= StatusBit.HEALTHY
        if cam.state is CameraState.STREAMING:
            status |= StatusBit.CAMERA_STREAMING
        else:
            faults |= FaultBit.CAMERA_LOST
        age = self.measurement_age_s()
        fresh = age is not None and age <= self.settings.measurement.max_age_s
        latest = self.latest
        if latest is not None and latest.status == "ok" and fresh:
            status |= StatusBit.MEASUREMENT_VALID
            if latest.in_tolerance:
                status |= StatusBit.IN_TOLERANCE
        elif latest is not None and latest.status != "ok":
            faults |= FaultBit.NO_MEASUREMENT
        if latest is not None and not fresh:
            faults |= FaultBit.STALE_MEASUREMENT
            self.bank.set("diameter", mm_to_units(None))
        c = self.channel.controller
        if c.settings.shadow:
            status |= StatusBit.SHADOW_MODE
        elif c.state in (State.ACTIVE, State.PENDING):
            status |= StatusBit.COMPENSATION_ACTIVE
        if c.state is State.ALARM:
            faults |= FaultBit.OUT_OF_TOLERANCE
        if c.state is State.STOPPED:
            faults |= FaultBit.SAFE_AREA_STOP
        if self.writer is not None:
            if self.writer.connected:
                status |= StatusBit.PLC_CONNECTED
            elif self.writer.outage_since is not None:
                faults |= FaultBit.OFFSET_WRITE_FAILED
        if c.state is State.UNCERTAIN:  # an offset the CNC has not settled: nothing moves
            faults |= FaultBit.OFFSET_WRITE_FAILED
        if self.geometry is not None:
            status |= StatusBit.CALIBRATED
        else:
            faults |= FaultBit.NO_CALIBRATION
        if c.writes_blocked:
            faults |= FaultBit.MASTER_CHECK_DUE
        age_ms = 65535 if age is None else min(65535, int(age * 1000))
        self.bank.set_many({"status": int(status), "faults": int(faults),
                            "measurement_age": age_ms})

    def status(self) -> dict[str, Any]:
        """Everything an operator or a monitoring system wants to know, JSON-ready."""
        cam = self.camera.status()
        c = self.channel.controller
        info = self.calibration[0].as_dict() if self.calibration else None
        writer = None
        if self.writer is not None:
            writer = {"host": self.writer.host, "port": self.writer.port,
                      "connected": self.writer.connected, "last_error": self.writer.last_error,
                      "outage_s": None if self.writer.outage_since is None else
                      time.monotonic() - self.writer.outage_since,
                      "last_write": None if self.channel.last_write is None else {
                          "outcome": self.channel.last_write.outcome.value,
                          "seq": self.channel.last_write.seq,
                          "message": self.channel.last_write.message}}
        age = self.measurement_age_s()
        tracker = None
        if self.tracker is not None:
            _, sigma = self.tracker.center()
            tracker = {"drift_um": [float(x * 1000) for x in self.tracker.drift_mm],
                       "sigma_um": sigma * 1000, "accepted": self.tracker.accepted,
                       "rejected": self.tracker.rejected}
        return {
            "healthy": self.healthy(), "problems": self.problems(),
            "uptime_s": time.time() - self.started,
            "camera": {"device_id": cam.device_id, "state": cam.state.value,
                       "message": cam.message, "counters": asdict(cam.counters)},
            "pipeline": {"method": self.method.value, "rate_hz": self.rate_hz(),
                         "frames_in": self.counters["frames_in"],
                         "measured": self.counters["measured"], "ok": self.counters["ok"],
                         "failed": self.counters["measured"] - self.counters["ok"],
                         "camera_dropped": cam.counters.dropped,
                         "subscriber_dropped": self.subscribers.dropped,
                         "compensation_dropped": self.counters["compensation_dropped"],
                         "errors": self.counters["pipeline_errors"],
                         "latest_age_s": age, "latency": self.latency_summary(),
                         "axis_tracking": tracker},
            "calibration": info, "store_error": self.store_error or None,
            "plc": writer,
            "modbus": {"enabled": self.settings.modbus.enabled,
                       "host": self.settings.modbus.host, "port": self.modbus.port,
                       "unit_id": self.settings.modbus.unit_id,
                       "requests": self.modbus.requests, "exceptions": self.modbus.exceptions},
            "compensation": {"state": c.state.value, "shadow": c.settings.shadow,
                             "cumulative_offset_mm": c.cumulative_mm,
                             "cnc_total_mm": c.persisted.cnc_total_mm,
                             "baseline_mm": c.persisted.baseline_mm,
                             "cnc_offset_from_baseline_mm": c.cnc_offset_mm(),
                             "max_total_mm": c.settings.max_total_mm,
                             "offset_seq": c.persisted.offset_seq,
                             "pending_seq": c.persisted.pending_seq,
                             "held": self.offset_hold(),
                             "log_rows": None if self.comp_log is None else
                             self.comp_log.rows_written},
            "master": self.master_status(),
            "temperature": {"part_temp_c": self.part_temp_c,
                            "alpha_per_k": self.alpha_per_k},
        }


def _settings_doc(comp: CompensationSettings, part_temp_c: float | None,
                  alpha_per_k: float) -> dict[str, Any]:
    """The runtime-changeable settings as stored (JSON-ready, compared after a round trip)."""
    return json.loads(json.dumps({"compensation": asdict(comp), "part_temp_c": part_temp_c,
                                  "alpha_per_k": alpha_per_k}))


def finite_or_none(x: float | None) -> float | None:
    """None for None, NaN and infinity."""
    return None if x is None or not math.isfinite(x) else x
