"""``shaftgauge serve``: build the gauge from its settings and run it behind uvicorn.

With ``camera.source = "sim"`` and ``plc.source = "sim"`` (the embedded default) the simulated
GigE camera and the simulated PLC run as child processes on loopback; they are stopped on exit
and die with the service if it is killed.
"""

from __future__ import annotations

import asyncio
import contextlib
import ctypes
import dataclasses
import gc
import json
import logging
import multiprocessing
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path

import uvicorn

from calib_store.compensation_log import CompensationLog, LogRetention
from calib_store.gauge_studies import GaugeStudyStore
from calib_store.job_store import JobStore
from calib_store.model import load_calibration
from calib_store.store import CalibrationStore, StoreError
from drivers.camera.base import Camera, CameraConfig
from drivers.plc.client import OffsetWriter
from drivers.plc.offset_map import PlcOffsetMap
from drivers.plc.pull import PullCnc
from drivers.plc.registers import RegisterBank, WordOrder
from drivers.plc.tls import TlsFiles, client_context
from service.api.app import create_app
from service.calibrate.session import CalibrationSessions
from service.compensation.job import OffsetEntry
from service.config import CameraSettings, PlcSettings, Settings
from service.https import https_files
from service.measure.diameter import MeasureParams
from service.measure.result import Method
from service.measure.runout_track import SpindleAngles
from service.measure.stripe import StripeParams
from service.quality.results import MeasureHandshake
from service.runtime.archive import MeasurementArchive
from service.runtime.calibration import CalibrationContext, MasterPolicy
from service.runtime.cnc_writes import CncCommands, CncWriteRules
from service.runtime.compensating import CompensationService, RuntimeSettings
from service.runtime.entry_channels import Transports
from service.runtime.feed import MeasurementFeed, SequenceCounter
from service.runtime.form_watch import FormWatch
from service.runtime.gauge import Gauge
from service.runtime.health import HealthReport
from service.runtime.job_service import JobService
from service.runtime.metrics import GaugeMetrics
from service.runtime.modbus import ModbusService
from service.runtime.offset_channel import OffsetTransport
from service.runtime.pipeline import FramePipeline
from service.runtime.plant import make_plant_links
from service.runtime.publish import Publisher
from service.runtime.register_view import RegisterView
from service.runtime.spc_service import SpcService
from service.runtime.studies import GaugeStudies, StudyPolicy

log = logging.getLogger("shaftgauge.serve")
_PR_SET_PDEATHSIG = 1


def _die_with_parent() -> None:  # runs in the child between fork and exec
    with contextlib.suppress(OSError):
        ctypes.CDLL("libc.so.6").prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)


@dataclass
class Children:
    """Simulators started for the embedded default."""

    procs: list[subprocess.Popen] = field(default_factory=list)

    def spawn(self, args: list[str], what: str, timeout_s: float = 60.0) -> dict:
        """Start one and wait for its ``ready`` line."""
        proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=None, text=True,
                                preexec_fn=_die_with_parent)
        self.procs.append(proc)
        line = proc.stdout.readline()
        if not line:
            raise RuntimeError(f"the simulated {what} did not start (exit code "
                               f"{proc.poll()}); see its message above")
        return json.loads(line)

    def stop(self, grace_s: float = 2.0) -> None:
        """Stop every child: SIGTERM, SIGKILL after ``grace_s``, and reaped either way (no
        zombie left)."""
        for proc in self.procs:
            if proc.poll() is None:
                proc.terminate()
        deadline = time.monotonic() + grace_s
        for proc in self.procs:
            try:
                proc.wait(max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        self.procs.clear()


def _shaftgauge() -> str:
    return str(Path(sys.executable).with_name("shaftgauge"))


SIM_PLC_TOOLS = 8
"""Tools with an offset block of their own in the simulated PLC (``sim-plc --tools``)."""
SIM_WEAR_UM_PER_MIN = 0.4
"""The embedded default's tool wear: 12 um on the diameter in a 30-minute insert."""


def sim_drift_um_per_min(cam: CameraSettings) -> float:
    """The simulated camera's wear drift the settings ask for."""
    if cam.sim_drift_um_per_min is not None:
        return cam.sim_drift_um_per_min
    return SIM_WEAR_UM_PER_MIN if cam.sim_feature else 0.0


SIM_FEED_MM_PER_MIN = 100.0
"""The simulated lathe's feed along the shaft: the laser's distance behind the tool follows
from it and the dead time asked."""


def sim_lathe_args(settings: Settings) -> list[str]:
    """The simulated camera's virtual lathe (``camera.sim_lathe``): its wear and dead time,
    and the CNC whose total it follows (the simulated PLC's, over Modbus)."""
    cam, plc = settings.camera, settings.plc
    if not cam.sim_lathe:
        return []
    period = cam.sim_drift_period_min
    lathe = {"wear_per_min_mm": sim_drift_um_per_min(cam) / 1000.0,
             "feed_mm_per_min": SIM_FEED_MM_PER_MIN,
             "laser_distance_mm": cam.sim_lathe_dead_time_s / 60.0 * SIM_FEED_MM_PER_MIN,
             "insert_every": max(1, round(period)) if period > 0 else 0,
             "thermal_mm": cam.sim_lathe_thermal_um / 1000.0,
             "thermal_tau_min": cam.sim_lathe_thermal_tau_s / 60.0}
    return ["--lathe", json.dumps(lathe), *(["--lathe-paced"] if cam.sim_lathe_paced else []),
            *_sim_cnc_args(plc)]


def _sim_cnc_args(plc: PlcSettings) -> list[str]:
    """The simulated PLC as the CNC whose totals a simulated part follows (none with
    another PLC: a test's own tells the camera)."""
    if plc.source != "sim":
        return []
    return ["--cnc", f"{plc.host}:{plc.port}", "--cnc-total-address", str(plc.total_address),
            "--cnc-unit-id", str(plc.unit_id), "--cnc-word-order", plc.word_order,
            "--cnc-tool-stride", str(plc.stride())]


def embedded_job(cam: CameraSettings) -> dict:
    """The embedded default's stepped shaft: its job, around the simulated diameter."""
    d = cam.sim_diameter_mm
    return {"part_number": "DEMO-4", "name": "simulated stepped shaft", "features": [
        {"number": 1, "name": "journal", "nominal_mm": d, "tol_upper_mm": 0.02,
         "tol_lower_mm": -0.02, "tool": 1},
        {"number": 2, "name": "bearing seat", "nominal_mm": round(d - 4.0, 3),
         "tol_upper_mm": 0.012, "tol_lower_mm": -0.012, "tool": 1},
        {"number": 3, "name": "collar", "nominal_mm": round(d + 4.0, 3), "tol_upper_mm": 0.025,
         "tol_lower_mm": -0.025, "tool": 2},
        {"number": 4, "name": "slender end", "nominal_mm": round(d - 2.0, 3),
         "tol_upper_mm": 0.015, "tol_lower_mm": -0.015, "tool": 2}]}


SIM_SETUP_MM = {"1": 0.007, "2": -0.011}
"""Where the embedded default's tools were set up, off their features' nominals: inside the
tolerances, so that the first parts are good and compensation has something to correct."""


def sim_stepped_args(settings: Settings) -> list[str]:
    """The simulated camera's stepped shaft (``camera.sim_part``), its tools wearing at
    the drift's rate and twice it, a new insert every ``sim_drift_period_min``, each set up
    off its nominals (``SIM_SETUP_MM``) and moved by its wear offset at the simulated CNC
    from the next part on."""
    cam = settings.camera
    if cam.source != "sim" or not (cam.sim_feature and cam.sim_part == "stepped") \
            or cam.sim_lathe:
        return []
    rate = sim_drift_um_per_min(cam)
    spec = {"segments": [{"diameter_mm": f["nominal_mm"], "tool": f["tool"],
                          "deflection_mm": 0.004 if f["number"] == 4 else 0.0}
                         for f in embedded_job(cam)["features"]],
            "dwell_s": 3.0, "wear_um_per_min": {"1": rate, "2": 2 * rate},
            "insert_every_min": cam.sim_drift_period_min, "part_sigma_mm": 0.0015,
            "seed": cam.sim_seed, "setup_mm": SIM_SETUP_MM}
    return ["--stepped", json.dumps(spec), *_sim_cnc_args(settings.plc)]


EMBEDDED_LOOP = {"shadow": False, "judge": "segment", "dead_time_measurements": 1,
                 "dead_time_s": 0.0}
"""The embedded default's loop on its stepped shaft and simulated CNC, closed: a segment a
feature a part, an offset showing from the next part on (a segment of its tool's later)."""


def embedded_feature(settings: Settings) -> Settings:
    """With the simulated camera, ``sim_feature`` on and no nominal set: the feature is the
    simulated shaft (``camera.sim_feature``); on the stepped shaft with the simulated PLC and
    no ``[compensation]`` of the settings' own, the loop closed (``EMBEDDED_LOOP``). An
    installation's compensation starts in shadow mode, as the installing page says."""
    cam, comp = settings.camera, settings.compensation
    if cam.source != "sim" or not cam.sim_feature or comp.nominal_mm is not None:
        return settings
    closed = sim_stepped_args(settings) and settings.plc.source == "sim" \
        and "compensation" not in settings.model_fields_set
    return settings.model_copy(update={"compensation": dataclasses.replace(
        comp, nominal_mm=cam.sim_diameter_mm, **(EMBEDDED_LOOP if closed else {}))})


def build(settings: Settings, children: Children) -> tuple[Gauge, dict]:
    """The gauge the settings describe, simulators started as needed, and what the simulators
    reported (their control port)."""
    extras: dict = {}
    settings = embedded_feature(settings)
    data_dir = settings.store.path.parent
    data_dir.mkdir(parents=True, exist_ok=True)
    store, comp_log, jobs, store_error = None, None, None, ""
    try:
        store = CalibrationStore(settings.store.path, settings.store.create_if_missing)
        jobs = JobStore(settings.store.path, settings.store.create_if_missing)
        comp_log = CompensationLog(settings.store.path, retention=LogRetention(
            settings.store.log_max_age_days, settings.store.log_max_rows,
            max_measurements=settings.store.archive_max_rows))
    except StoreError as err:
        store_error = str(err)
        log.error("%s", err)

    cam_cfg = settings.camera
    config = CameraConfig(
        exposure_us=cam_cfg.exposure_us, gain_db=cam_cfg.gain_db,
        pixel_format=cam_cfg.pixel_format, frame_rate_hz=cam_cfg.frame_rate_hz,
        packet_size=cam_cfg.packet_size, packet_socket=cam_cfg.packet_socket,
        socket_buffer_bytes=cam_cfg.socket_buffer_bytes, queue_size=cam_cfg.queue_size,
        trigger=cam_cfg.trigger, trigger_line=cam_cfg.trigger_line)
    camera: Camera
    if cam_cfg.source == "rig":
        from drivers.camera.rig_camera import RigCamera

        camera = RigCamera(cam_cfg.sim_diameter_mm, config, seed=cam_cfg.sim_seed,
                           replay_frames=cam_cfg.sim_replay_frames)
        sim_cal = camera.renderer.calibration
    else:
        from drivers.camera.aravis import AravisCamera

        sim_cal = None
        device_id = cam_cfg.device_id
        if cam_cfg.source == "sim":
            cal_path = data_dir / "sim-calibration.json"
            ready = children.spawn(
                [_shaftgauge(), "sim-camera", "--serial", cam_cfg.sim_serial, "--diameter",
                 str(cam_cfg.sim_diameter_mm), "--fps", str(cam_cfg.frame_rate_hz or 10.0),
                 "--drift-um-per-min", str(sim_drift_um_per_min(cam_cfg)),
                 "--drift-period-min", str(cam_cfg.sim_drift_period_min), "--seed",
                 str(cam_cfg.sim_seed), "--replay", str(cam_cfg.sim_replay_frames),
                 "--calibration-out", str(cal_path), *sim_lathe_args(settings),
                 *sim_stepped_args(settings)], "camera")
            device_id = ready["device_id"]
            extras["sim_camera_control_port"] = ready["control_port"]
            sim_cal = load_calibration(cal_path)
        if not device_id:
            raise ValueError("camera.device_id: needed with camera.source = 'gige' "
                             "(see `shaftgauge camera list`)")
        camera = AravisCamera(device_id, config)

    writer = None
    plc = settings.plc
    if plc.source == "sim":
        state = data_dir / "sim-plc.state"
        children.spawn([_shaftgauge(), "sim-plc", "--host", plc.host, "--port", str(plc.port),
                        "--unit-id", str(plc.unit_id), "--offset-address",
                        str(plc.offset_address), "--ack-address", str(plc.ack_address),
                        "--total-address", str(plc.total_address), "--word-order",
                        plc.word_order, "--tools", str(SIM_PLC_TOOLS if plc.stride() else 0),
                        "--tool-stride", str(plc.stride() or 10),
                        "--ack-delay", str(plc.sim_ack_delay_s), "--log",
                        str(data_dir / "sim-plc.log"), "--state", str(state)], "PLC")
    if plc.source in ("sim", "modbus"):
        offsets = PlcOffsetMap(plc.offset_address, plc.ack_address, plc.total_address,
                               plc.unit_id, WordOrder(plc.word_order), plc.stride())
        if plc.stride():
            offsets.for_offset(SIM_PLC_TOOLS)  # ValueError now, not at a job's first offset
        writer = OffsetWriter(plc.host, plc.port, offsets, ack_timeout_s=plc.ack_timeout_s,
            sslctx=client_context(TlsFiles(plc.tls.certfile, plc.tls.keyfile, plc.tls.cafile))
            if plc.tls else None)

    if store is not None and sim_cal is not None and not store.list():
        store.add(sim_cal, by="shaftgauge", note="simulated rig (embedded default)",
                  activate=True)
    if jobs is not None and sim_stepped_args(settings) and not jobs.list():
        jobs.add(embedded_job(cam_cfg), by="shaftgauge", note="simulated stepped shaft "
                 "(embedded default)", activate=True)
    extras["camera"] = device_id if cam_cfg.source != "rig" else "rig"
    return wire(settings, camera, store, comp_log, writer, store_error, jobs), extras


def pull_transport(cnc: PullCnc, entry: OffsetEntry) -> OffsetTransport:
    """An entry's transport over the pull handshake: its request names tool and entry."""
    return cnc.entry(entry.tool, entry.number or 0)


def push_transport(writer: OffsetWriter, entry: OffsetEntry) -> OffsetTransport:
    """An entry's transport to a CNC the gauge writes to: its offset number's block (a
    tool's own entry: its T number's)."""
    return writer.offset(entry.number or entry.tool)


def wire(settings: Settings, camera: Camera, store: CalibrationStore | None,
         comp_log: CompensationLog | None, writer: OffsetWriter | PullCnc | None,
         store_error: str = "", job_store: JobStore | None = None) -> Gauge:
    """The one place where the gauge's parts are made and connected."""
    ms, ts = settings.measurement, settings.temperature
    bank = RegisterBank(settings.modbus.word_order)
    if settings.plc.source == "pull":
        if not settings.modbus.enabled:
            raise ValueError("plc.source = 'pull': the CNC polls the gauge's Modbus server, "
                             "so modbus.enabled must be true")
        writer = PullCnc(bank, settings.modbus.host, settings.modbus.port,
                         ack_timeout_s=settings.plc.ack_timeout_s)
    transport: Transports | None = None
    if isinstance(writer, PullCnc):
        transport = partial(pull_transport, writer)
    elif isinstance(writer, OffsetWriter):
        transport = partial(push_transport, writer)
    sp = settings.spindle
    context = CalibrationContext(store, MasterPolicy(ms.master_interval_h, ms.axis_sigma_mm,
                                                     ms.track_axis), store_error,
                                 SpindleAngles(sp.deg_per_frame, sp.zero_deg)
                                 if sp.source == "encoder" else None)
    compensation = CompensationService(
        RuntimeSettings(settings.compensation, ts.part_temp_c, ts.alpha_per_k), transport,
        comp_log, reset_command=settings.modbus.reset_command, store_error=store_error)
    feed = MeasurementFeed(ms.history, ms.fuse_frames)
    compensation.on_decision(feed.decisions.publish)
    context.on_change(compensation.set_calibration)
    context.on_change(lambda _: feed.restart_fusion())
    params = MeasureParams(stripe=StripeParams(optics_blur_px=ms.optics_blur_px),
                           axis_sigma_mm=ms.axis_sigma_mm, free_fit=ms.track_axis,
                           sheet_correction=ms.sheet_correction,
                           sheet_sigma_mm=ms.sheet_sigma_mm)
    registers = RegisterView(bank, compensation)
    rules = CncWriteRules(settings.modbus, compensation)
    commands = CncCommands(settings.modbus, compensation, registers, camera.software_trigger)
    modbus = ModbusService(settings.modbus, bank, registers, rules.check, commands.take)
    compensation.on_decision(registers.decided)
    sequence = SequenceCounter(comp_log, compensation.last_measurement_seq() + 1)
    jobs = JobService(job_store, compensation, store_error,
                      MeasureHandshake(settings.modbus.result_measurements,
                                       settings.modbus.result_within_s))
    compensation.on_settings(lambda _: jobs.settings_changed())
    rules.jobs = commands.jobs = jobs
    registers.show_jobs(jobs)
    jobs.on_change(registers.job_changed)
    jobs.on_results(registers.show_results)
    jobs.on_new_job(registers.show_results)
    publisher = Publisher(sequence, feed, registers, compensation, jobs, sp.max_tir_mm)
    pipeline = FramePipeline(camera, context, Method(ms.method), params, ms.workers, publisher,
                             settings.camera.roi_margin_px if settings.camera.roi_enabled
                             else None, ms.max_rate_hz, ms.reflection_check_hz,
                             ms.processes)
    health = HealthReport(settings, camera, context, pipeline, feed, compensation, writer,
                          modbus)
    context.load_active()
    api = settings.api
    sessions = CalibrationSessions(settings.store.path.parent / "calibration-sessions",
                                   api.max_calibration_sessions, api.max_session_images,
                                   api.session_expiry_h, api.calibration_step_budget_s)
    if comp_log is not None and settings.store.archive_hz > 0:  # for the AQDEF export
        feed.on_publish(MeasurementArchive(comp_log, settings.store.archive_hz,
                                           jobs.feature_for, health.form_position))
    feed.on_publish(jobs.published)
    health.jobs = jobs
    spc = SpcService(settings.spc, ms.fuse_frames, jobs.feature_for)
    jobs.on_new_job(spc.forget)
    jobs.on_new_job(feed.restart_fusion)  # another job's features are others
    feed.on_publish(spc)
    q = settings.quality
    studies = GaugeStudies(
        GaugeStudyStore(settings.store.path) if store is not None else None, feed,
        compensation, ms.fuse_frames,
        StudyPolicy(q.study_max_age_h, q.min_index, q.study_required, q.resolution_mm),
        lambda: context.calibration[0].id if context.calibration else None)
    health.quality = (spc, studies)
    form = FormWatch(context) if context.spindle is not None else None
    health.form = form
    made = make_plant_links(settings, feed, compensation, camera, writer, health, jobs)
    if made.mqtt is not None:
        feed.on_publish(made.mqtt.measurement)
        compensation.on_decision(made.mqtt.decision)
        jobs.part_log.on_part(made.mqtt.part)
    if made.opcua_values is not None:
        compensation.on_decision(made.opcua_values.last_offset)
    plant = made.links
    health.plant = plant
    metrics = GaugeMetrics(health)
    feed.on_publish(metrics.record)
    pipeline.stage_listener = metrics.stage_time
    compensation.on_write(lambda r: metrics.write_time(r.outcome.value, r.elapsed_s))
    return Gauge(settings, camera, context, pipeline, feed, compensation, modbus, health,
                 sessions, metrics, spc, studies, jobs, writer, comp_log, plant, form, commands)


STOP_MARGIN_S = 1.5
"""How long a stop may take before it is cut short: beyond ``api.shutdown_s`` once serving,
from the signal while starting."""


class _Server(uvicorn.Server):
    """uvicorn's server that, told to stop, ends the live streams first (they never end by
    themselves, and uvicorn waits for open connections before it stops), and is sure to stop:
    a stop that hangs (a start that never finished, a part that does not end) is cut short
    after ``api.shutdown_s`` plus a margin, its children stopped first."""

    def __init__(self, feed: MeasurementFeed, config: uvicorn.Config, children: Children,
                 last_words: Callable[[], None]) -> None:
        super().__init__(config)
        self._feed = feed
        self._children = children
        self._last_words = last_words
        self.stopped_by: int | None = None

    def handle_exit(self, sig: int, frame: object) -> None:
        if self.stopped_by is None:
            # Said, since "Shutting down" alone does not tell a signal from outside apart.
            log.warning("stopping: %s received", signal.Signals(sig).name)
            # A start still under way (compiling kernels, connecting) ends only when it is
            # done; nothing serves yet, so there is nothing to drain either.
            deadline = STOP_MARGIN_S + (self.config.timeout_graceful_shutdown or 0.0
                                        if self.started else 0.0)
            threading.Thread(target=self._cut_short, args=(deadline, sig),
                             name="stop-deadline", daemon=True).start()
        self.stopped_by = sig
        with contextlib.suppress(RuntimeError):  # no loop running: nothing streams
            asyncio.get_running_loop().call_soon(self._feed.closing.set)
        super().handle_exit(sig, frame)

    def _cut_short(self, deadline_s: float, sig: int) -> None:
        time.sleep(deadline_s)
        still = sorted(t.name for t in threading.enumerate()
                       if t.is_alive() and t is not threading.current_thread())
        log.error("the service did not stop within %.1f s of the signal (still running: %s): "
                  "its children are stopped and it exits", deadline_s, ", ".join(still))
        with contextlib.suppress(Exception):
            self._last_words()
        for proc in multiprocessing.active_children():  # measuring workers, compilers
            proc.kill()
        self._children.stop(grace_s=0.5)
        logging.shutdown()
        os._exit(128 + sig)

    @contextlib.contextmanager
    def capture_signals(self) -> Iterator[None]:
        # uvicorn raises a caught signal again once it has stopped, which kills the process
        # before ``serve`` stops the children and says how it ended: it is kept in stopped_by.
        with super().capture_signals():
            try:
                yield
            finally:
                self._captured_signals.clear()


@contextlib.contextmanager
def _stop_raises() -> Iterator[None]:
    """SIGTERM raises SystemExit (143) meanwhile, so that ``finally`` clauses run (uvicorn
    puts its own handler in place while it serves, and this one back after)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def stop(sig: int, _: object) -> None:
        raise SystemExit(128 + sig)

    previous = signal.signal(signal.SIGTERM, stop)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def api_listener(host: str, port: int) -> socket.socket:
    """The API's listening socket, bound before anything else starts: a port in use ends the
    start at once (RuntimeError naming it), with nothing started and nothing left listening
    (uvicorn binds after the application's start-up, and its shutdown then waited for a
    start that had the CNC's Modbus port open)."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    try:
        return socket.create_server((host, port), family=family, backlog=2048)
    except OSError as err:
        raise RuntimeError(f"the API cannot listen on {host}:{port} (api.port: is another "
                           f"program using it?): {err.strerror or err}") from None


async def serve(settings: Settings) -> int:
    """Run until SIGINT or SIGTERM."""
    tls = https_files(settings.api, settings.store.path.parent)
    listener = api_listener(settings.api.host, settings.api.port)
    children = Children()
    try:
        gauge, extras = build(settings, children)
    except BaseException:
        children.stop()
        listener.close()
        raise
    app = create_app(gauge)

    def last_words() -> None:  # what is decided is on disk, even when the stop is cut short
        if gauge.log is not None:
            gauge.log.flush(1.0)

    server = _Server(gauge.feed, uvicorn.Config(app, host=settings.api.host, port=settings.api.port,
                                           log_level=settings.log_level, access_log=False,
                                           limit_concurrency=settings.api.max_connections,
                                           proxy_headers=bool(settings.api.trusted_proxies),
                                           forwarded_allow_ips=settings.api.trusted_proxies
                                           or None,
                                           timeout_graceful_shutdown=settings.api.shutdown_s,
                                           ssl_certfile=tls and str(tls.certfile),
                                           ssl_keyfile=tls and str(tls.keyfile)),
                     children, last_words)

    async def announce() -> None:
        while not server.started:
            await asyncio.sleep(0.05)
        port = server.servers[0].sockets[0].getsockname()[1] if server.servers else \
            settings.api.port
        host = settings.api.host if settings.api.host not in ("0.0.0.0", "::") else "127.0.0.1"
        base = f"{'https' if tls else 'http'}://{host}:{port}"
        https = {"tls_sha256": tls.sha256} if tls else {}
        print(json.dumps({"event": "ready", "url": base, "api_port": port, **https,
                          "modbus_port": gauge.modbus.port if settings.modbus.enabled
                          else None, **extras}), flush=True)
        print(f"shaftgauge is up. Dashboard: {base}/ui/  API docs: {base}/docs  "
              f"Modbus TCP: {settings.modbus.host}:{gauge.modbus.port}", file=sys.stderr,
              flush=True)
        if tls:
            print(f"HTTPS certificate {tls.certfile}: SHA-256 fingerprint {tls.sha256} "
                  "(compare it with what the browser shows)", file=sys.stderr, flush=True)
        # What start-up built (modules, the app, the OPC UA address space: 400,000 objects)
        # lives as long as the process: out of the collector's full passes, which otherwise
        # walk all of it and stop the event loop for 25-200 ms each (frames dropped, the
        # registers late). Again once the plant links have built theirs.
        for wait_s in (0.0, 3.0):
            await asyncio.sleep(wait_s)
            gc.collect()
            gc.freeze()

    try:
        task = asyncio.get_running_loop().create_task(announce())
        await server.serve(sockets=[listener])
        task.cancel()
    finally:
        listener.close()
        children.stop()
    return 130 if server.stopped_by == signal.SIGINT else 0


def main(settings: Settings) -> int:
    """Configure logging and run."""
    logging.basicConfig(level=settings.log_level.upper(),
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    # asyncua tells every node it builds at INFO (a thousand lines a start): its warnings only,
    # unless asked for debug.
    if settings.log_level != "debug":
        logging.getLogger("asyncua").setLevel(logging.WARNING)
    os.environ.setdefault("PYTHONUNBUFFERED", "1")
    try:
        # Outside uvicorn's own handling (starting the simulators, before it serves and
        # after), SIGTERM raises SystemExit so that the children are stopped on the way out.
        with _stop_raises():
            return asyncio.run(serve(settings))
    except KeyboardInterrupt:  # Ctrl-C: uvicorn stopped everything, then raised it again
        return 130
