"""What is wrong and how the service stands: a read-only view over the other parts."""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass
from typing import Any

from drivers.camera.base import Camera, CameraState
from drivers.plc.client import OffsetWriter
from drivers.plc.pull import PullCnc
from service.api.attempts import attempts_for  # a counter, no router
from service.compensation import State
from service.config import Settings
from service.runtime.calibration import CalibrationContext
from service.runtime.compensating import CompensationService
from service.runtime.feed import MeasurementFeed
from service.runtime.modbus import ModbusService
from service.runtime.pipeline import FramePipeline
from service.runtime.status_words import StatusSnapshot


@dataclass(frozen=True)
class Problem:
    """One thing wrong now: a stable ``code`` for programs and tests, ``text`` for people."""

    code: str
    text: str

    def as_dict(self) -> dict[str, str]:
        """JSON-ready."""
        return {"code": self.code, "text": self.text}


class HealthReport:
    """Reads the parts; changes nothing."""

    def __init__(self, settings: Settings, camera: Camera, context: CalibrationContext,
                 pipeline: FramePipeline, feed: MeasurementFeed,
                 compensation: CompensationService, writer: OffsetWriter | PullCnc | None,
                 modbus: ModbusService) -> None:
        self.settings, self.camera, self.context = settings, camera, context
        self.pipeline, self.feed, self.compensation = pipeline, feed, compensation
        self.writer, self.modbus = writer, modbus
        self.started = time.time()
        self.running = False
        self.plant: list[Any] = []  # service.runtime.plant.PlantLink, set by the gauge
        self.quality: tuple[Any, Any] | None = None  # (SpcService, GaugeStudies), set too
        self.form: Any = None  # service.runtime.form_watch.FormWatch, with the spindle's angle
        self.jobs: Any = None  # service.runtime.job_service.JobService, set too

    def _fresh(self) -> bool:
        age = self.feed.measurement_age_s()
        return age is not None and age <= self.settings.measurement.max_age_s

    def healthy(self) -> bool:
        """Camera streaming, calibrated, and a fresh good measurement."""
        latest = self.feed.latest
        return bool(self.running and self.camera.status().state is CameraState.STREAMING
                    and self.context.geometry is not None and latest is not None
                    and latest.status == "ok" and self._fresh())

    def ready(self) -> bool:
        """Healthy, and what it decides can be kept: a store it cannot write (a full disk)
        makes the gauge unready (``/readyz``), while it goes on measuring (the heartbeat)."""
        return self.healthy() and not self.compensation.log_problem()

    def problems(self) -> list[Problem]:
        """What is wrong now (empty when all is well)."""
        out = []
        cam = self.camera.status()
        streaming = cam.state is CameraState.STREAMING
        if not streaming:
            out.append(Problem(f"camera_{cam.state.value}",
                               f"camera {cam.state.value}: {cam.message}"))
        if self.context.store_error:
            out.append(Problem("store", self.context.store_error))
        if self.context.geometry is None:
            out.append(Problem("no_calibration",
                               "no calibration is active: import and activate one"))
        elif streaming:
            latest = self.feed.latest
            if not self._fresh():
                out.append(Problem("no_recent_measurement", "no recent measurement"))
            elif latest is not None and latest.status != "ok":
                out.append(Problem("not_measuring",
                                   f"latest frame did not measure: {latest.reason}"))
        runout, watch = self._position()
        limit = self.settings.spindle.max_tir_mm
        if runout is not None:  # measured about the surface's own centre: the watch waits
            if runout.tir_mm > limit:
                out.append(Problem("runout", (
                    f"run-out {runout.tir_mm * 1000:.0f} um TIR (limit {limit * 1000:.0f} um): "
                    "the surface under the laser is not concentric with the spindle (raw "
                    "stock, a bad clamping, a bent part): no offset is written from it")))
        elif watch is not None and not (verdict := watch.verdict()).concentric:
            out.append(Problem("not_concentric", verdict.reason + ": its diameters are "
                               "refused and no offset is written from them"))
        if self.jobs is not None and self.jobs.store_error:
            out.append(Problem("job", self.jobs.store_error))
        comp = self.compensation
        if comp.log_problem():
            lost = comp.log.lost_measurements if comp.log else 0
            out.append(Problem("log_unwritable", comp.log_problem()
                               + ": offsets are neither proposed nor written meanwhile"
                               + (f"; {lost} archived measurements lost" if lost else "")))
        hold = comp.offset_hold()
        if hold:
            out.append(Problem("offsets_held", f"offsets held: {hold}"))
        w = self.writer
        if w is not None and not w.connected and w.outage_since is not None:
            out.append(Problem("plc_unreachable", f"CNC/PLC unreachable: {w.last_error}"))
        in_force = comp.in_force()
        several = len(in_force) > 1
        for e, ch in in_force:
            state = ch.controller.state.value
            if ch.controller.state in (State.ALARM, State.STOPPED, State.UNCERTAIN):
                out.append(Problem(f"compensation_{state}", f"compensation of {e} {state}"
                                   if several else f"compensation {state}"))
        study = self.quality[1].blocking() if self.quality else None
        blocked = dict.fromkeys(ch.controller.writes_blocked for _, ch in in_force
                                if ch.controller.writes_blocked not in ("", study))
        out += [Problem("offsets_blocked", f"offsets blocked: {why}") for why in blocked]
        if study:  # its own code: the study, not the master check, blocks
            out.append(Problem("gauge_study", study + ": offsets are only proposed"))
        out += [Problem(code, text) for link in self.plant for code, text in link.problems()]
        return out

    def summary(self) -> dict[str, Any]:
        """The short health a plant system watches (MQTT ``health``), JSON-ready."""
        latest, cam = self.feed.latest, self.camera.status()
        return {"healthy": self.healthy(), "problems": [p.as_dict() for p in self.problems()],
                "uptime_s": time.time() - self.started, "camera": cam.state.value,
                "rate_hz": self.feed.rate_hz(),
                "latest_status": None if latest is None else latest.status,
                "compensation": self.compensation.state.value,
                "calibration_id": None if latest is None else latest.calibration_id,
                "form": self.form_position()}

    def form_position(self) -> dict[str, Any]:
        """The run-out and roundness of the surface under the laser (None where not known):
        ``tir_mm``, ``eccentricity_deg``, ``ront_mm``, ``lobes`` (0: none above the noise)."""
        runout, _ = self._position()
        shape = self.form.latest if self.form is not None and runout is not None else None
        shape = shape if shape is not None and shape.ok else None
        return {"tir_mm": None if runout is None else runout.tir_mm,
                "eccentricity_deg": None if runout is None else runout.eccentricity_deg,
                "ront_mm": None if shape is None else shape.ront_mm,
                "lobes": None if shape is None else shape.dominant_order}

    def snapshot(self) -> StatusSnapshot:
        """The registers' view of the moment."""
        latest = self.feed.latest
        w = self.writer
        runout, watch = self._position()
        form = self.form_position()
        return StatusSnapshot(
            healthy=self.healthy(),
            camera_streaming=self.camera.status().state is CameraState.STREAMING,
            calibrated=self.context.geometry is not None,
            latest_status=None if latest is None else latest.status,
            latest_in_tolerance=None if latest is None else latest.in_tolerance,
            age_s=self.feed.measurement_age_s(),
            max_age_s=self.settings.measurement.max_age_s,
            shadow=self.compensation.settings.shadow, compensation=self.compensation.state,
            plc_configured=w is not None, plc_connected=w is not None and w.connected,
            plc_outage=w is not None and w.outage_since is not None,
            writes_blocked=bool(self.context.master_status()["blocking"]),
            rule_violation=bool(self.quality and self.quality[0].rule_violation),
            study_failed=bool(self.quality and self.quality[1].blocking()),
            not_concentric=(latest is not None and latest.status == "not_concentric") or (
                runout is None and watch is not None and not watch.verdict().concentric),
            tir_mm=form["tir_mm"], runout_phase_deg=form["eccentricity_deg"],
            max_tir_mm=self.settings.spindle.max_tir_mm, ront_mm=form["ront_mm"],
            lobes=form["lobes"] or 0)

    def _position(self) -> tuple[Any, Any]:
        """The run-out of the calibration in force (when known) and its concentricity
        watch."""
        in_use = self.context.in_use
        if in_use is None:
            return None, None
        return (in_use.runout.runout if in_use.runout is not None else None,
                in_use.concentricity)

    def status(self) -> dict[str, Any]:
        """Everything an operator or a monitoring system wants to know, JSON-ready."""
        cam = self.camera.status()
        feed, ctx, comp = self.feed, self.context, self.compensation
        info = ctx.calibration[0].as_dict() if ctx.calibration else None
        tracker = None
        if ctx.tracker is not None:
            _, sigma = ctx.tracker.center()
            tracker = {"drift_um": [float(x * 1000) for x in ctx.tracker.drift_mm],
                       "sigma_um": sigma * 1000, "accepted": ctx.tracker.accepted,
                       "rejected": ctx.tracker.rejected}
        runout = None
        if ctx.in_use is not None and ctx.in_use.runout is not None:
            sp = self.settings.spindle
            runout = {**ctx.in_use.runout.status(), "source": sp.source,
                      "deg_per_frame": sp.deg_per_frame, "max_tir_mm": sp.max_tir_mm,
                      "roundness": self.form.status() if self.form is not None else None}
        counters = feed.counters
        m = self.settings.modbus
        return {
            "healthy": self.healthy(), "ready": self.ready(),
            "problems": [p.as_dict() for p in self.problems()],
            "uptime_s": time.time() - self.started,
            "camera": {"device_id": cam.device_id, "state": cam.state.value,
                       "message": cam.message, "counters": asdict(cam.counters),
                       "region": None if cam.region is None else list(cam.region),
                       "auto_roi": self.pipeline.roi_margin_px is not None},
            "pipeline": {"method": self.pipeline.method.value, "rate_hz": feed.rate_hz(),
                         "frames_in": self.pipeline.counters["frames_in"],
                         "measured": counters["measured"], "ok": counters["ok"],
                         "failed": counters["measured"] - counters["ok"],
                         "camera_dropped": cam.counters.dropped,
                         "subscriber_dropped": feed.subscribers.dropped,
                         "compensation_dropped": comp.dropped,
                         "errors": self.pipeline.counters["errors"],
                         "workers": {"count": self.pipeline.workers,
                                     "processes": self.pipeline.processes,
                                     "restarts": self.pipeline.counters["worker_restarts"],
                                     "frames_lost": self.pipeline.counters[
                                         "frames_lost_with_a_worker"]},
                         "reflection": {
                             "present": self.pipeline.reflections.present,
                             "modelled_frames": self.pipeline.counters["reflections_modelled"]},
                         "latest_age_s": feed.measurement_age_s(),
                         "latency": feed.latency_summary(), "axis_tracking": tracker,
                         "runout": runout,
                         "position_settled": None if ctx.in_use is None
                         else ctx.in_use.settling.settled},
            "calibration": info, "store_error": ctx.store_error or None,
            "plc": self._plc(),
            "api": {"https": self.settings.api.tls_certfile is not None
                             or self.settings.api.tls_self_signed,
                    "wrong_keys": attempts_for(self.settings.api).refused},
            "modbus": {"enabled": m.enabled, "host": m.host, "port": self.modbus.port,
                       "unit_id": m.unit_id, "requests": self.modbus.server.requests,
                       "exceptions": self.modbus.server.exceptions,
                       "connections": self.modbus.server.connections,
                       "refused_connections": self.modbus.server.refused_connections,
                       "refused_writes": self.modbus.server.refused_writes,
                       "last_refused": self.modbus.server.last_refused,
                       "tls": self.modbus.server.tls is not None,
                       "refused_handshakes": self.modbus.server.tls_refusals.count,
                       "last_refused_handshake": self.modbus.server.tls_refusals.last},
            "compensation": comp.status(),
            "job": self.jobs.status() if self.jobs is not None else None,
            "master": ctx.master_status(),
            "temperature": {"part_temp_c": comp.part_temp_c, "alpha_per_k": comp.alpha_per_k},
            "plant": {link.name: link.status() for link in self.plant},
            "quality": None if self.quality is None else {
                "rule_violation": self.quality[0].rule_violation,
                "gauge_study": self.quality[1].status()},
        }

    def _plc(self) -> dict[str, Any] | None:
        w = self.writer
        if w is None:
            return None
        last = self.compensation.last_write()
        return {"host": w.host, "port": w.port, "connected": w.connected,
                "last_error": w.last_error,
                "outage_s": None if w.outage_since is None else
                time.monotonic() - w.outage_since,
                "last_write": None if last is None else {
                    "outcome": last.outcome.value, "seq": last.seq, "message": last.message}}
