"""The camera interface: configuration, frames, counters and status."""

from __future__ import annotations

import abc
import enum
import logging
import threading
from dataclasses import dataclass, field, replace

import numpy as np

from drivers.camera.queue import DropOldestQueue

log = logging.getLogger("shaftgauge.camera")

PIXEL_FORMATS = ("Mono8", "Mono12", "Mono16")
NO_REGION_REQUEST = object()
TRIGGER_MODES = ("free_run", "software", "hardware")


class CameraError(RuntimeError):
    """A camera that cannot be opened or configured; the message says what and why."""


@dataclass(frozen=True)
class CameraConfig:
    """What to ask of a camera. ``None`` leaves the camera's own setting.

    Attributes
    ----------
    exposure_us : float or None
        Exposure time, microseconds.
    gain_db : float or None
        Analogue gain, dB (or the camera's gain unit).
    region : tuple of int or None
        (x, y, width, height) in pixels; None for the camera's current region.
    pixel_format : str or None
        ``Mono8`` (uint8 frames), ``Mono12`` or ``Mono16`` (uint16 frames); None keeps the
        camera's own (frames of 8 or 16 bits per pixel are delivered, others refused).
    frame_rate_hz : float or None
        Frame rate in free-run mode.
    trigger : str
        ``free_run``, ``software`` (``Camera.software_trigger``) or ``hardware``.
    trigger_line : str
        Input line of the hardware trigger (GenICam name, e.g. ``Line0``).
    packet_size : int or None
        GigE Vision stream packet size, bytes; None negotiates the largest that works.
    packet_socket : bool
        Let Aravis use a packet socket when it runs as root (faster); False forces the
        ordinary UDP socket that an unprivileged service uses.
    socket_buffer_bytes : int or None
        None: Aravis sizes the stream socket's receive buffer to the payload (AUTO). A size
        fixes it (FIXED), capped by the kernel's ``net.core.rmem_max``: an unprivileged
        receiver of a camera that bursts whole frames needs a few megabytes.
    n_buffers : int
        Pre-allocated stream buffers.
    queue_size : int
        Frames held for a slow consumer before the oldest is dropped.
    reconnect_initial_s, reconnect_max_s : float
        Backoff between reconnection attempts: doubles from the first to the most.
    """

    exposure_us: float | None = None
    gain_db: float | None = None
    region: tuple[int, int, int, int] | None = None
    pixel_format: str | None = "Mono8"
    frame_rate_hz: float | None = None
    trigger: str = "free_run"
    trigger_line: str = "Line0"
    packet_size: int | None = None
    packet_socket: bool = True
    socket_buffer_bytes: int | None = None
    n_buffers: int = 8
    queue_size: int = 4
    reconnect_initial_s: float = 0.5
    reconnect_max_s: float = 5.0

    def __post_init__(self) -> None:
        if self.pixel_format is not None and self.pixel_format not in PIXEL_FORMATS:
            raise CameraError(f"pixel_format {self.pixel_format!r}: use one of {PIXEL_FORMATS}")
        if self.trigger not in TRIGGER_MODES:
            raise CameraError(f"trigger {self.trigger!r}: use one of {TRIGGER_MODES}")
        if self.n_buffers < 2 or self.queue_size < 1:
            raise CameraError("n_buffers must be >= 2 and queue_size >= 1")


@dataclass
class BlockIds:
    """A stream's frame numbers from its block ids, which in GigE Vision 1.x are 16 bits and
    go from 65535 to 1 (0 is not a block id): counted on across that wrap, so that they keep
    rising; an id that goes back by less than half the range is the camera starting again,
    and is taken as it comes."""

    _last: int | None = None
    _wraps: int = 0

    def count(self, block_id: int) -> int:
        """The frame number of this block id."""
        if self._last is not None and block_id < self._last:
            if self._last - block_id > 0x8000 and self._last <= 0xFFFF:
                self._wraps += 1
            else:
                self._wraps = 0
        self._last = block_id
        return block_id + self._wraps * 0xFFFF


@dataclass(frozen=True)
class Frame:
    """One complete image.

    Attributes
    ----------
    image : ndarray, shape (H, W)
        uint8 for Mono8, uint16 for Mono12/Mono16.
    frame_id : int
        The camera's frame number, counting on across the 16-bit block ids of GigE Vision
        1.x (``BlockIds``): a frame triggered by the spindle's encoder is at a known angle
        from it.
    timestamp_ns : int
        The device's timestamp, as it came (ns, device clock).
    received_ns : int
        ``time.monotonic_ns()`` when the driver received it.
    origin : (int, int) or None
        None for a whole sensor's frame; when the camera reads a region of interest, the
        sensor position (x, y, px) of the image's top-left pixel.
    """

    image: np.ndarray
    frame_id: int
    timestamp_ns: int
    received_ns: int
    origin: tuple[int, int] | None = None


class CameraState(enum.StrEnum):
    """Where the driver is."""

    STOPPED = "stopped"
    CONNECTING = "connecting"
    STREAMING = "streaming"
    LOST = "lost"            # the camera went away; reconnection follows
    RECONNECTING = "reconnecting"
    FAILED = "failed"        # cannot be opened as configured; a person must act


@dataclass
class CameraCounters:
    """Running totals since ``start``, carried across reconnections."""

    completed: int = 0        # complete frames handed on
    failed: int = 0           # buffers that arrived incomplete or late, never handed on
    missing_packets: int = 0
    resent_packets: int = 0
    underruns: int = 0        # the camera had no free buffer to fill
    dropped: int = 0          # frames dropped because the consumer was slow
    reconnects: int = 0
    region_changes: int = 0   # regions of interest applied


@dataclass(frozen=True)
class CameraStatus:
    """A snapshot of the driver, safe to hand to another thread."""

    device_id: str
    state: CameraState
    message: str
    counters: CameraCounters = field(default_factory=CameraCounters)
    last_frame_ns: int | None = None
    region: tuple[int, int, int, int] | None = None  # the region read; None: whole sensor


@dataclass(frozen=True)
class DeviceInfo:
    """A camera found on the network."""

    device_id: str
    vendor: str
    model: str
    serial: str
    address: str
    protocol: str


class Camera(abc.ABC):
    """A source of frames with its own acquisition thread.

    ``start`` returns at once; frames then arrive in a bounded queue that ``get_frame`` reads.
    The driver survives the camera going away: it reports the loss in ``status`` and
    reconnects by itself. No exception escapes its thread.
    """

    @abc.abstractmethod
    def start(self) -> None:
        """Start acquisition (idempotent)."""

    @abc.abstractmethod
    def stop(self) -> None:
        """Stop acquisition and end the acquisition thread (idempotent)."""

    @abc.abstractmethod
    def get_frame(self, timeout_s: float | None = None) -> Frame | None:
        """The oldest queued frame, waiting up to ``timeout_s``; None on timeout or stop."""

    @abc.abstractmethod
    def status(self) -> CameraStatus:
        """State, message and counters."""

    def software_trigger(self) -> None:
        """Ask for one frame (trigger mode ``software``)."""
        raise CameraError("this camera has no software trigger")

    def set_region(self, region: tuple[int, int, int, int] | None) -> None:
        """Ask the camera to read only ``region`` (x, y, width, height, px) of its sensor,
        None for the whole sensor. Applied by the acquisition thread between frames, rounded
        to the increments the camera reports; frames carry the region they were read with
        (``Frame.origin`` and the image's size)."""
        raise CameraError("this camera cannot change its region of interest")

    def __enter__(self) -> Camera:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


class ThreadedCamera(Camera):
    """A camera with its own acquisition thread (``_run``), a drop-oldest frame queue and a
    status shared under a lock: the bookkeeping every implementation needs."""

    def __init__(self, device_id: str, config: CameraConfig) -> None:
        self.device_id = device_id
        self.config = config
        self._queue: DropOldestQueue[Frame] = DropOldestQueue(config.queue_size)
        self._lock = threading.Lock()  # status fields
        self._state = CameraState.STOPPED
        self._message = "not started"
        self._counters = CameraCounters()
        self._last_frame_ns: int | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        # A region asked for and not yet applied; NO_REGION_REQUEST when none is pending.
        self._region_request: object = NO_REGION_REQUEST
        self._region_now: tuple[int, int, int, int] | None = None

    @abc.abstractmethod
    def _run(self) -> None:
        """The acquisition loop; returns when ``self._stop`` is set."""

    def start(self) -> None:
        if self._thread and self._thread.is_alive():
            return
        self._stop.clear()
        self._queue.reopen()
        self._thread = threading.Thread(target=self._run, name=f"camera:{self.device_id}",
                                        daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._wake()
        if self._thread:
            self._thread.join(timeout=15.0)
            if self._thread.is_alive():  # pragma: no cover - a driver hung in a call
                log.error("camera thread of %s did not end within 15 s", self.device_id)
        self._thread = None
        self._queue.close()
        self._set_state(CameraState.STOPPED, "stopped")

    def _wake(self) -> None:
        """Wake the acquisition thread if it waits on something besides ``_stop``."""

    def set_region(self, region: tuple[int, int, int, int] | None) -> None:
        if region is not None and (len(region) != 4 or min(region[2:]) < 1
                                   or min(region[:2]) < 0):
            raise CameraError(f"region {region}: give (x >= 0, y >= 0, width >= 1, "
                              "height >= 1) in pixels")
        with self._lock:
            self._region_request = None if region is None else tuple(int(v) for v in region)

    def _take_region_request(self) -> object:
        """The region asked for since the last call (``NO_REGION_REQUEST`` if none)."""
        with self._lock:
            request, self._region_request = self._region_request, NO_REGION_REQUEST
        return request

    def get_frame(self, timeout_s: float | None = None) -> Frame | None:
        return self._queue.get(timeout_s)

    def status(self) -> CameraStatus:
        with self._lock:
            counters = replace(self._counters, dropped=self._queue.dropped)
            return CameraStatus(self.device_id, self._state, self._message, counters,
                                self._last_frame_ns, self._region_now)

    def _region_applied(self, region: tuple[int, int, int, int] | None) -> None:
        """Record the region now read (None: the whole sensor) and count the change."""
        with self._lock:
            if region != self._region_now:
                self._counters.region_changes += 1
            self._region_now = region

    def _set_state(self, state: CameraState, message: str) -> None:
        with self._lock:
            changed = state != self._state or message != self._message
            self._state, self._message = state, message
        if changed:
            log.info("camera %s: %s (%s)", self.device_id, state.value, message)

    def _deliver(self, frame: Frame) -> None:
        """Hand a complete frame to the consumer (never blocks) and count it."""
        self._queue.put(frame)
        with self._lock:
            self._counters.completed += 1
            self._last_frame_ns = frame.received_ns
