"""Any GigE Vision camera (or Aravis's in-process fake) through Aravis 0.8 and PyGObject.

One acquisition thread per camera: it opens and configures the camera, pre-allocates a pool of
stream buffers, pops them with a timeout, hands only complete frames on (copied, the buffer
pushed back at once) to a bounded drop-oldest queue, and watches for the camera going away
(Aravis's ``control-lost`` signal, a stalled stream whose camera no longer answers, or one that
stays stalled though the camera answers). Then it tears everything down and reconnects with
exponential backoff: re-discover, re-open, re-configure, resume. Opening stops any acquisition
a predecessor left running (a service killed while streaming leaves the camera sending to a
dead address). Nothing raised inside the thread escapes it; what happened is in
``status()``.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from drivers.camera.base import (
    NO_REGION_REQUEST,
    BlockIds,
    CameraConfig,
    CameraError,
    CameraState,
    DeviceInfo,
    Frame,
    ThreadedCamera,
)

log = logging.getLogger("shaftgauge.camera")

_STOP_WAIT_S = 1.0
_POP_TIMEOUT_US = 100_000
# A free-running stream that delivers nothing for this long gets its camera probed.
_STALL_S = 2.0
# One that still delivers nothing this long, though its camera answers, is opened afresh: the
# camera streams elsewhere (its previous controller died without closing: a killed service).
_RESTART_S = 3.0


def _aravis() -> Any:
    """The Aravis GI module (imported lazily so that pure code never needs GObject)."""
    import gi

    gi.require_version("Aravis", "0.8")
    from gi.repository import Aravis

    return Aravis


def _glib_error() -> type[Exception]:
    from gi.repository import GLib

    return GLib.Error


_fake_lock = threading.Lock()


def enable_fake_interface() -> None:
    """Make Aravis's in-process fake camera (device id ``Fake_1``) discoverable."""
    with _fake_lock:
        _aravis().enable_interface("Fake")


def list_devices() -> list[DeviceInfo]:
    """Every camera Aravis sees (GigE Vision, USB3 Vision, and the fake when enabled)."""
    Aravis = _aravis()
    Aravis.update_device_list()
    return [
        DeviceInfo(
            device_id=Aravis.get_device_id(i) or "",
            vendor=Aravis.get_device_vendor(i) or "",
            model=Aravis.get_device_model(i) or "",
            serial=Aravis.get_device_serial_nbr(i) or "",
            address=Aravis.get_device_address(i) or "",
            protocol=Aravis.get_device_protocol(i) or "",
        )
        for i in range(Aravis.get_n_devices())
    ]


def bits_per_pixel(pixel_format: int) -> int:
    """Bits per pixel of a GenICam pixel format code (bits 16-23 of the PFNC value)."""
    return (int(pixel_format) >> 16) & 0xFF


@dataclass
class _Session:
    """The Aravis objects of one connection."""

    camera: Any
    device: Any
    stream: Any
    handler_id: int
    lost: threading.Event
    packet_size: int | None
    infos: dict[str, str]  # our counter -> the stream's info name, for the infos it has
    sensor: tuple[int, int] = (0, 0)                  # width, height, px
    region: tuple[int, int, int, int] = (0, 0, 0, 0)  # x, y, width, height in force
    previous: tuple[int, int, int, int] = (0, 0, 0, 0)  # ... and before the last change
    ids: BlockIds = field(default_factory=BlockIds)    # frame numbers from block ids


_STREAM_INFOS = {
    "failed": "n_failures",
    "underruns": "n_underruns",
    "missing_packets": "n_missing_packets",
    "resent_packets": "n_resent_packets",
}


class AravisCamera(ThreadedCamera):
    """A GigE Vision camera through Aravis.

    Parameters
    ----------
    device_id : str
        Aravis device id (``shaftgauge camera list``), e.g. ``Basler-21234567`` or
        ``Aravis-Fake-SIM001``; ``Fake_1`` after ``enable_fake_interface()``.
    config : CameraConfig
        What to configure on every (re)connection.
    """

    def __init__(self, device_id: str, config: CameraConfig | None = None) -> None:
        super().__init__(device_id, config or CameraConfig())
        self._cam_lock = threading.Lock()      # control-channel calls from two threads
        self._stream_base = dict.fromkeys(_STREAM_INFOS, 0)
        self._session: _Session | None = None

    def software_trigger(self) -> None:
        with self._cam_lock:
            session = self._session
            if session is None:
                raise CameraError(f"{self.device_id}: not connected")
            try:
                session.camera.software_trigger()
            except _glib_error() as err:
                raise CameraError(f"{self.device_id}: software trigger failed: "
                                  f"{err.message}") from None

    # ---- the acquisition thread ----------------------------------------------------------

    def _run(self) -> None:
        backoff = self.config.reconnect_initial_s
        first = True
        while not self._stop.is_set():
            try:
                self._set_state(CameraState.CONNECTING if first else CameraState.RECONNECTING,
                                f"opening {self.device_id}")
                session = self._open()
            except CameraError as err:  # the camera answers but refuses our configuration
                self._set_state(CameraState.FAILED, f"{err}; retrying in "
                                f"{self.config.reconnect_max_s:g} s")
                self._stop.wait(self.config.reconnect_max_s)
                continue
            except Exception as err:  # not found, not reachable, taken by another host
                wait = backoff
                backoff = min(backoff * 2.0, self.config.reconnect_max_s)
                state = CameraState.CONNECTING if first else CameraState.RECONNECTING
                self._set_state(state, f"cannot open {self.device_id}: {_describe(err)}; "
                                f"retrying in {wait:g} s")
                self._stop.wait(wait)
                continue
            if not first:
                with self._lock:
                    self._counters.reconnects += 1
            first = False
            backoff = self.config.reconnect_initial_s
            with self._cam_lock:
                self._session = session
            self._set_state(CameraState.STREAMING,
                            f"streaming (packet size {session.packet_size or 'n/a'})")
            try:
                reason = self._stream(session)
            except Exception as err:  # pragma: no cover - defensive: keep the thread alive
                reason = f"acquisition error: {_describe(err)}"
                log.exception("camera %s", self.device_id)
            if reason:  # say so at once: releasing a dead camera takes seconds of timeouts
                self._set_state(CameraState.LOST, f"{reason}; reconnecting")
            with self._cam_lock:
                self._session = None
            self._close(session, lost=bool(reason))

    def _open(self) -> _Session:
        Aravis = _aravis()
        GLibError = _glib_error()
        cfg = self.config
        Aravis.update_device_list()
        camera = Aravis.Camera.new(self.device_id)
        device = camera.get_device()
        lost = threading.Event()
        handler_id = device.connect("control-lost", lambda *_: lost.set())
        try:
            # An acquisition left running by a predecessor that died without closing (a killed
            # service) streams to its old destination: stop it before setting ours.
            with contextlib.suppress(GLibError):
                camera.stop_acquisition()
            packet_size = self._configure(camera, Aravis)
            stream = camera.create_stream(None, None)
            if stream is None:
                raise CameraError("cannot create a stream")
            if hasattr(Aravis, "GvStream") and isinstance(stream, Aravis.GvStream):
                if cfg.socket_buffer_bytes:
                    stream.set_property("socket-buffer", Aravis.GvStreamSocketBuffer.FIXED)
                    stream.set_property("socket-buffer-size", int(cfg.socket_buffer_bytes))
                else:
                    stream.set_property("socket-buffer", Aravis.GvStreamSocketBuffer.AUTO)
            sensor = tuple(int(v) for v in camera.get_sensor_size())
            # Buffers that hold a whole sensor's frame: a region can then change (narrow or
            # widen) without allocating again.
            bytes_per_px = max(1, bits_per_pixel(camera.get_pixel_format()) // 8)
            payload = max(camera.get_payload(), sensor[0] * sensor[1] * bytes_per_px)
            for _ in range(cfg.n_buffers):
                stream.push_buffer(Aravis.Buffer.new_allocate(payload))
            camera.start_acquisition()
        except GLibError as err:
            device.disconnect(handler_id)
            raise CameraError(f"{self.device_id}: {err.message}") from None
        except Exception:
            device.disconnect(handler_id)
            raise
        names = {stream.get_info_name(i) for i in range(stream.get_n_infos())}
        infos = {k: v for k, v in _STREAM_INFOS.items() if v in names}
        region = tuple(int(v) for v in camera.get_region())
        self._region_applied(None if region == (0, 0, *sensor) else region)  # type: ignore[arg-type]
        return _Session(camera, device, stream, handler_id, lost, packet_size, infos,
                        sensor, region, region)  # type: ignore[arg-type]

    def _apply_region(self, session: _Session, region: tuple[int, int, int, int] | None
                      ) -> None:
        """Stop acquisition, set the sensor region (None: the whole sensor) rounded to the
        camera's increments, and start again; frames read before carry the old region."""
        GLibError = _glib_error()
        cam = session.camera
        sw, sh = session.sensor
        x, y, w, h = (0, 0, sw, sh) if region is None else region
        with self._cam_lock:
            try:
                xi, yi = max(1, cam.get_x_offset_increment()), max(1, cam.get_y_offset_increment())
                wi, hi = max(1, cam.get_width_increment()), max(1, cam.get_height_increment())
                x, y = min(x, sw - 1) // xi * xi, min(y, sh - 1) // yi * yi
                w = min(-(-w // wi) * wi, (sw - x) // wi * wi)
                h = min(-(-h // hi) * hi, (sh - y) // hi * hi)
                cam.stop_acquisition()
                cam.set_region(x, y, w, h)  # Aravis zeroes the offsets, sets the size, then them
                applied = tuple(int(v) for v in cam.get_region())
                cam.start_acquisition()
            except GLibError as err:
                with self._lock:
                    self._message = f"cannot set region {(x, y, w, h)}: {err.message}"
                with contextlib.suppress(GLibError):
                    cam.start_acquisition()
                return
        session.previous, session.region = session.region, applied  # type: ignore[assignment]
        self._region_applied(None if applied == (0, 0, sw, sh) else applied)

    def _configure(self, camera: Any, Aravis: Any) -> int | None:
        """Apply the configuration; return the stream packet size (GigE only)."""
        cfg = self.config
        GLibError = _glib_error()

        def attempt(what: str, fn: Any, *args: Any) -> None:
            try:
                fn(*args)
            except GLibError as err:
                raise CameraError(f"{self.device_id}: cannot set {what}: {err.message}") \
                    from None

        if cfg.pixel_format:
            attempt("pixel format " + cfg.pixel_format, camera.set_pixel_format_from_string,
                    cfg.pixel_format)
        if cfg.region is not None:
            attempt(f"region {cfg.region}", camera.set_region, *cfg.region)
        if cfg.exposure_us is not None and camera.is_exposure_time_available():
            attempt("exposure", camera.set_exposure_time, float(cfg.exposure_us))
        if cfg.gain_db is not None and camera.is_gain_available():
            attempt("gain", camera.set_gain, float(cfg.gain_db))
        if cfg.trigger == "free_run":
            if camera.is_feature_available("TriggerMode"):
                attempt("free-run trigger mode", camera.clear_triggers)
            if cfg.frame_rate_hz is not None and camera.is_frame_rate_available():
                attempt("frame rate", camera.set_frame_rate, float(cfg.frame_rate_hz))
        elif cfg.trigger == "software":
            attempt("software trigger", camera.set_trigger, "Software")
        else:
            attempt(f"hardware trigger on {cfg.trigger_line}", camera.set_trigger,
                    cfg.trigger_line)
        if not camera.is_gv_device():
            return None
        if not cfg.packet_socket:
            camera.gv_set_stream_options(Aravis.GvStreamOption.PACKET_SOCKET_DISABLED)
        if cfg.packet_size:
            attempt(f"packet size {cfg.packet_size}", camera.gv_set_packet_size,
                    int(cfg.packet_size))
        else:
            attempt("packet size (negotiated)", camera.gv_auto_packet_size)
        return int(camera.gv_get_packet_size())

    def _stream(self, session: _Session) -> str:
        """Pop buffers until stop (returns '') or loss (returns the reason)."""
        Aravis = _aravis()
        success = Aravis.BufferStatus.SUCCESS
        stream = session.stream
        last_ok = time.monotonic()
        while not self._stop.is_set():
            if session.lost.is_set():
                return f"camera {self.device_id} lost (no answer to control messages)"
            request = self._take_region_request()
            if request is not NO_REGION_REQUEST:
                self._apply_region(session, request)  # type: ignore[arg-type]
                last_ok = time.monotonic()
            buf = stream.timeout_pop_buffer(_POP_TIMEOUT_US)
            self._update_stream_counters(session)
            if buf is None:
                quiet_s = time.monotonic() - last_ok
                if self.config.trigger == "free_run" and quiet_s > _STALL_S:
                    if not self._answers(session):
                        return f"camera {self.device_id} lost (stream stalled, camera silent)"
                    if quiet_s > _RESTART_S:
                        return (f"camera {self.device_id} answers but sent no frame for "
                                f"{quiet_s:.0f} s (stream stalled)")
                continue
            if buf.get_status() != success:
                stream.push_buffer(buf)
                continue
            try:
                frame = self._to_frame(buf, session)
            finally:
                stream.push_buffer(buf)  # back to the pool at once: get_data() copied it
            if frame is None:
                continue
            last_ok = time.monotonic()
            self._deliver(frame)
        return ""

    def _answers(self, session: _Session) -> bool:
        """Whether the camera still answers a control read."""
        try:
            with self._cam_lock:
                session.camera.get_payload()
            return True
        except Exception:
            return False

    def _to_frame(self, buf: Any, session: _Session) -> Frame | None:
        w, h = buf.get_image_width(), buf.get_image_height()
        # Which region it was read with: the one in force, or (a frame read just before a
        # change) the one before; anything else is not handed on.
        region = next((r for r in (session.region, session.previous) if r[2:] == (w, h)),
                      None)
        if region is None:
            log.warning("camera %s: frame %d is %dx%d, the region is %s", self.device_id,
                        buf.get_frame_id(), w, h, session.region)
            return None
        bits = bits_per_pixel(buf.get_image_pixel_format())
        if bits not in (8, 16):
            with self._lock:
                self._message = f"unsupported pixel format ({bits} bits per pixel)"
            return None
        dtype = np.uint8 if bits == 8 else np.dtype("<u2")
        data = buf.get_data()
        need = w * h * (bits // 8)
        if len(data) < need:  # a buffer that reported success yet is short: never hand it on
            log.warning("camera %s: frame %d has %d bytes, %dx%d needs %d", self.device_id,
                        buf.get_frame_id(), len(data), w, h, need)
            return None
        image = np.frombuffer(data, dtype=dtype, count=w * h).reshape(h, w)
        if bits == 16:
            image = image.astype(np.uint16, copy=False)
        whole = region == (0, 0, *session.sensor)
        return Frame(image, session.ids.count(int(buf.get_frame_id())), int(buf.get_timestamp()),
                     time.monotonic_ns(), None if whole else (region[0], region[1]))

    def _update_stream_counters(self, session: _Session) -> None:
        stream = session.stream
        values = {k: int(stream.get_info_uint64_by_name(v)) for k, v in session.infos.items()}
        with self._lock:
            for k, v in values.items():
                setattr(self._counters, k, self._stream_base[k] + v)

    def _close(self, session: _Session, lost: bool) -> None:
        """Stop and release everything of one connection, dead camera or not.

        When the camera is being stopped (the service shuts down) this waits at most
        ``_STOP_WAIT_S``: a camera that died a moment ago (a simulated one, stopped by the same
        Ctrl-C) answers neither the stop nor the release of control that dropping the device
        sends, and Aravis's retries would hold the shutdown for seconds. The release goes on
        in the background; whatever is left running is stopped by the next open."""
        self._update_stream_counters(session)
        with self._lock:
            for k in session.infos:
                self._stream_base[k] = getattr(self._counters, k)
        parts = (session.camera, session.stream, session.device, session.handler_id)
        session.stream = session.camera = session.device = None
        if not self._stop.is_set():
            _release(parts, lost, self.device_id)
            return
        done = threading.Event()
        threading.Thread(target=_release, args=(parts, lost, self.device_id, done),
                         daemon=True, name="camera-release").start()
        del parts
        if not done.wait(_STOP_WAIT_S):
            log.info("camera %s did not answer its release within %g s (gone already?)",
                     self.device_id, _STOP_WAIT_S)

def _release(parts: tuple, lost: bool, device_id: str,
             done: threading.Event | None = None) -> None:
    """Stop a connection's acquisition (unless the camera is lost: the command would only time
    out) and drop its last references, which ends Aravis's stream and heartbeat threads."""
    camera, stream, device, handler_id = parts
    del parts
    try:
        if not lost:
            try:
                camera.stop_acquisition()
            except Exception as err:
                log.debug("stop_acquisition on %s: %s", device_id, _describe(err))
        with contextlib.suppress(Exception):
            device.disconnect(handler_id)
        del camera, stream, device
    finally:
        if done is not None:
            done.set()


def _describe(err: Exception) -> str:
    return getattr(err, "message", None) or str(err) or type(err).__name__
