"""A simulated GigE Vision camera that streams the simulated rig's stripe images.

Aravis's ``ArvGvFakeCamera`` speaks real GVCP and GVSP on an IPv4 address (127.0.0.1 here) and
is discoverable like any GigE Vision camera. PyGObject cannot hold a Python callback for its
fill pattern (a "scope call" argument), so the library is driven through ctypes. A renderer
thread keeps the next frame ready; the fill callback, called by Aravis's streaming thread, only
copies it into the buffer (whose size reads 0 there: it holds width * height bytes).

Each frame's first row carries a stamp: bytes 0-7 the frame counter and bytes 8-11 the CRC-32
of rows 1 onward (little-endian), so tests can prove that no incomplete frame was delivered.
The diameter (with a wear drift), the packet loss ratio and the frame rate can be changed while
it runs, and it can show a calibration board instead of the shaft (``show_board``: a pose in
front of the camera, with or without the laser line, or clamped between the centres), so that a
calibration session can capture its images from the live camera.

It honours the sensor region a client sets (GenICam ``OffsetX``/``OffsetY``/``Width``/
``Height``: the frames sent are that window of the sensor, stamped as whole frames are) and,
as a real sensor, cannot run faster than its rows can be read (``replay.min_frame_period_us``:
fewer rows, a higher frame rate). With ``replay_frames`` it renders a ring of frames at start
and then only sends them (``replay.FrameRing``), so that it does not compete with the gauge
for the CPU.
"""

from __future__ import annotations

import ctypes
import logging
import math
import threading
import time
import zlib
from collections.abc import Callable, Mapping
from ctypes import CFUNCTYPE, POINTER, byref, c_char_p, c_double, c_size_t, c_uint32, c_void_p
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from drivers.sim.board_shots import Board, BoardRenderer, Shot
from drivers.sim.disturb import Disturbances
from drivers.sim.lathe import LaserView, LatheConfig, VirtualLathe
from drivers.sim.replay import FrameRing, crop, min_frame_period_us
from drivers.sim.rig import RigConfig, ShaftRenderer, Turning
from drivers.sim.stepped import SteppedPart

log = logging.getLogger("shaftgauge.sim.gige")

_REG_WIDTH, _REG_HEIGHT = 0x100, 0x104
_REG_SENSOR_HEIGHT, _REG_SENSOR_WIDTH = 0x118, 0x11C
_REG_FRAME_PERIOD_US = 0x138
_REG_OFFSET_X, _REG_OFFSET_Y = 0x130, 0x134
STAMP_BYTES = 12

_FillPattern = CFUNCTYPE(None, c_void_p, c_void_p, c_uint32, c_uint32, c_uint32)


def _libs() -> tuple[ctypes.CDLL, ctypes.CDLL]:
    lib = ctypes.CDLL("libaravis-0.8.so.0")
    gobject = ctypes.CDLL("libgobject-2.0.so.0")
    lib.arv_gv_fake_camera_new_full.restype = c_void_p
    lib.arv_gv_fake_camera_new_full.argtypes = [c_char_p, c_char_p, c_char_p]
    lib.arv_gv_fake_camera_is_running.restype = ctypes.c_int
    lib.arv_gv_fake_camera_is_running.argtypes = [c_void_p]
    lib.arv_gv_fake_camera_get_fake_camera.restype = c_void_p
    lib.arv_gv_fake_camera_get_fake_camera.argtypes = [c_void_p]
    lib.arv_fake_camera_write_register.argtypes = [c_void_p, c_uint32, c_uint32]
    lib.arv_fake_camera_read_register.argtypes = [c_void_p, c_uint32, POINTER(c_uint32)]
    lib.arv_fake_camera_set_fill_pattern.argtypes = [c_void_p, _FillPattern, c_void_p]
    lib.arv_buffer_get_data.restype = c_void_p
    lib.arv_buffer_get_data.argtypes = [c_void_p, POINTER(c_size_t)]
    gobject.g_object_unref.argtypes = [c_void_p]
    return lib, gobject


def stamp(counter: int, image: np.ndarray, crc: int | None = None) -> bytes:
    """The 12 stamp bytes of a frame: its counter and the CRC-32 of its rows 1.. (given when
    known), little-endian."""
    crc = zlib.crc32(image[1:].tobytes()) if crc is None else crc
    return int(counter).to_bytes(8, "little") + crc.to_bytes(4, "little")


def stamp_frame(image: np.ndarray, counter: int) -> None:
    """Write the frame counter and the CRC-32 of rows 1.. into the first 12 bytes, in place."""
    image.reshape(-1)[:STAMP_BYTES] = np.frombuffer(stamp(counter, image), np.uint8)


def check_stamp(image: np.ndarray) -> tuple[int, bool]:
    """(frame counter, whether the CRC of rows 1.. matches) of a stamped 8-bit frame."""
    flat = image.reshape(-1)
    counter = int.from_bytes(flat[:8].tobytes(), "little")
    crc = int.from_bytes(flat[8:12].tobytes(), "little")
    return counter, crc == zlib.crc32(image[1:].tobytes())


@dataclass
class SimCameraSettings:
    """What a simulated GigE camera shows; the ``set_*`` methods change it while running."""

    serial: str = "SIM001"
    address: str = "127.0.0.1"
    diameter_mm: float = 30.0
    drift_um_per_min: float = 0.0
    drift_period_min: float = 0.0  # > 0: the drift starts again this often (a new insert)
    fps: float = 10.0
    lost_ratio: float = 0.0
    seed: int = 0
    rig: RigConfig = field(default_factory=RigConfig)
    replay_frames: int = 0
    """0: render every frame; N: render a ring of N frames and send them in turn."""
    spindle_deg_per_frame: float = 0.0
    """How far the spindle turns from one frame to the next (``rig.turning`` shows it; 0, or
    a multiple of 360: a frame rate locked to the spindle)."""
    lathe: LatheConfig | None = None
    """A virtual lathe decides the diameter shown (continuous turning, the laser a dead time
    behind the tool; ``set_cnc_total`` or its ``follow`` tell it the CNC's wear offset);
    ``diameter_mm`` and the drift are then not used."""
    lathe_paced: bool = False
    """The lathe's time stands at 0 until ``advance`` moves it (else: the wall clock from
    the camera's start until the first ``advance``)."""
    stepped: SteppedPart | None = None
    """A stepped shaft, part after part, its segments in turn (``drivers.sim.stepped``);
    ``diameter_mm`` and the drift are then not used, until ``set_diameter`` (a master put
    in) ends it."""


class CameraLathe:
    """The virtual lathe behind a simulated camera (continuous turning, ``LaserView``): what
    it cuts is what the camera shows; thread-safe. Its time runs from its start on the wall
    clock until ``advance`` drives it (``paced``: from the start): then only as a test moves
    it (in step with the gauge's measurements, so that a slow or loaded machine slows the
    lathe with the gauge)."""

    def __init__(self, config: LatheConfig, seed: int = 0, paced: bool = False) -> None:
        self._view = LaserView(VirtualLathe(config, seed=seed))
        self._lock = threading.Lock()
        self._t0 = time.monotonic()
        self._driven: float | None = 0.0 if paced else None
        self.cnc_error = ""

    def _now(self) -> float:
        """The lathe's time, s (the caller holds the lock)."""
        return time.monotonic() - self._t0 if self._driven is None else self._driven

    def advance(self, seconds: float) -> float:
        """Drive the lathe's time: ``seconds`` on from where it is (the first call stops its
        wall clock there); the lathe's time now."""
        if not (math.isfinite(seconds) and 0 <= seconds <= 3600):
            raise ValueError("advance the lathe by 0 to 3600 s")
        with self._lock:
            self._driven = self._now() + float(seconds)
            return self._driven

    def set_total(self, total_mm: float) -> None:
        """The CNC holds a total wear offset of ``total_mm`` (mm of diameter) from now on:
        what is cut from now on, and seen a dead time later, moves by it."""
        with self._lock:
            self._view.cnc_total(self._now(), float(total_mm))

    def follow(self, read_total_mm: Callable[[], float], stop: threading.Event,
               period_s: float = 0.2) -> None:
        """Read the CNC's total every ``period_s`` in a thread of its own until ``stop``
        (``read_total_mm`` raises OSError or ValueError when it cannot: the last total stays,
        the error shows in the stats)."""
        def follow() -> None:
            while not stop.wait(period_s):
                try:
                    self.set_total(read_total_mm())
                    self.cnc_error = ""
                except (OSError, ValueError) as err:
                    self.cnc_error = str(err) or type(err).__name__
        threading.Thread(target=follow, name="sim-lathe-cnc", daemon=True).start()

    def new_insert(self) -> None:
        """A new insert goes in now: what is cut from now on (seen a dead time later) starts
        its wear again. The CNC's wear offset is whoever zeroes it."""
        with self._lock:
            self._view.lathe.change_insert_at(self._now() / 60.0)

    def diameter_mm(self) -> float:
        """The diameter under the laser now, mm."""
        with self._lock:
            return self._view.diameter_mm(self._now())

    def stats(self) -> dict[str, float | str]:
        """The sample under the laser now, and the CNC's total it knows."""
        with self._lock:
            now = self._now()
            cut = self._view.cut_under_laser(now)
            total = self._view.total_at(now)
        return {"time_s": round(now, 4), "driven": self._driven is not None,
                "cut_diameter_mm": round(cut.diameter_mm, 7), "wear_mm": round(cut.wear_mm, 7),
                "offset_in_cut_mm": round(cut.offset_mm, 7), "cnc_total_mm": round(total, 7),
                "dead_time_s": self._view.dead_time_s, "cnc_error": self.cnc_error}


class CameraStepped:
    """The stepped part behind a simulated camera, its tools moved by their wear offsets at
    the CNC: a part is cut with the offsets in force when it comes under the tool, so an
    offset shows from the next part on; thread-safe."""

    def __init__(self, part: SteppedPart) -> None:
        self.part = part
        self._lock = threading.Lock()
        self._cnc_mm: dict[int, float] = {}  # each tool's wear offset at the CNC now
        self._cut: tuple[int, dict[int, float]] = (-1, {})  # the part under the laser, and
        self.cnc_error = ""                                 # the offsets it was cut with

    def follow(self, readers: Mapping[int, Callable[[], float]], stop: threading.Event,
               period_s: float = 0.2) -> None:
        """Read each tool's wear offset (mm of diameter) every ``period_s`` in a thread of
        its own until ``stop``; a reader that fails (OSError, ValueError) leaves its tool's
        as it was, said in the stats."""
        def follow() -> None:
            while not stop.wait(period_s):
                errors = []
                for tool, read in readers.items():
                    try:
                        total = float(read())
                    except (OSError, ValueError) as err:
                        errors.append(f"tool {tool}: {err or type(err).__name__}")
                        continue
                    with self._lock:
                        self._cnc_mm[tool] = total
                self.cnc_error = "; ".join(errors)
        threading.Thread(target=follow, name="sim-stepped-cnc", daemon=True).start()

    def diameter_mm(self, t_s: float) -> float:
        """The diameter under the laser ``t_s`` seconds from the start."""
        with self._lock:
            if self.part.part_at(t_s) != self._cut[0]:  # the next part: cut with those now
                self._cut = (self.part.part_at(t_s), dict(self._cnc_mm))
            return self.part.at(t_s, self._cut[1])

    def stats(self) -> dict[str, Any]:
        """The part under the laser, the offsets it was cut with, and a reading's failure."""
        with self._lock:
            return {"part": self._cut[0], "offsets_mm": {str(k): v for k, v in
                                                          self._cut[1].items()},
                    "cnc_error": self.cnc_error}


class SimGigECamera:
    """The simulated GigE Vision camera, in this process (run it in its own process for tests
    that kill it: ``shaftgauge sim-camera``)."""

    def __init__(self, settings: SimCameraSettings) -> None:
        self.settings = settings
        self.renderer = ShaftRenderer(settings.rig, seed=settings.seed)
        self._lib, self._gobject = _libs()
        self._lock = threading.Lock()
        self._ready: np.ndarray | None = None   # next frame to send
        self._want = threading.Event()
        self._stop = threading.Event()
        self._counter = 0
        self._sent = 0
        self._repeats = 0
        self._t0 = time.monotonic()
        self._d0 = settings.diameter_mm
        self.lathe = CameraLathe(settings.lathe, settings.seed, settings.lathe_paced) \
            if settings.lathe is not None else None
        self.stepped = CameraStepped(settings.stepped) if settings.stepped is not None \
            else None
        self._scene: tuple[Shot, Board] | None = None   # None: the shaft
        self._scene_image: tuple[tuple[Shot, Board], np.ndarray] | None = None
        self._gv: int | None = None
        self._callback = _FillPattern(self._fill)  # keep a reference: C holds the pointer
        self._ring = FrameRing(self.renderer, settings.replay_frames, self.current_diameter) \
            if settings.replay_frames > 0 else None
        self._requested_period_us = 0   # the period the client asked for (before clamping)
        self._written_period_us = 0     # ... and the one written to the register
        self._thread = threading.Thread(target=self._render_loop, name="sim-render", daemon=True)

    # ---- life cycle ------------------------------------------------------------------------

    def start(self) -> None:
        """Render the first frame (or the replay ring), then start serving GVCP/GVSP on the
        address."""
        if self._ring is not None:
            self._ring.fill()
        self._ready = self._render_next()
        w, h = self.settings.rig.image_size
        gv = self._lib.arv_gv_fake_camera_new_full(
            self.settings.address.encode(), self.settings.serial.encode(), None)
        if not gv or not self._lib.arv_gv_fake_camera_is_running(gv):
            raise RuntimeError(f"cannot serve a GigE Vision camera on {self.settings.address} "
                               "(address not on this host, or port 3956 taken?)")
        self._gv = gv
        fake = self._lib.arv_gv_fake_camera_get_fake_camera(gv)
        for reg, value in ((_REG_SENSOR_WIDTH, w), (_REG_SENSOR_HEIGHT, h), (_REG_WIDTH, w),
                           (_REG_HEIGHT, h)):
            self._lib.arv_fake_camera_write_register(fake, reg, value)
        self.set_fps(self.settings.fps)
        self.set_lost_ratio(self.settings.lost_ratio)
        self._lib.arv_fake_camera_set_fill_pattern(fake, self._callback, None)
        self._thread.start()

    def stop(self) -> None:
        """Stop serving (the camera vanishes from the network)."""
        self._stop.set()
        self._want.set()
        if self._gv:
            self._gobject.g_object_unref(self._gv)
            self._gv = None
        if self._thread.is_alive():
            self._thread.join(timeout=5)

    @property
    def device_id(self) -> str:
        """The Aravis device id clients open it by."""
        return f"Aravis-Fake-{self.settings.serial}"

    # ---- live changes ------------------------------------------------------------------

    def set_diameter(self, diameter_mm: float, drift_um_per_min: float | None = None) -> None:
        """Jump to a diameter (a master put in ends a stepped part), and the drift if given."""
        if self.lathe is not None:
            raise ValueError("the virtual lathe decides the diameter shown: tell it the "
                             "CNC's offset ('cnc_total_mm'), not a diameter")
        with self._lock:
            self._d0, self._t0, self.settings.stepped = float(diameter_mm), time.monotonic(), None
            if drift_um_per_min is not None:
                self.settings.drift_um_per_min = float(drift_um_per_min)

    def set_disturbances(self, spec: Disturbances) -> None:
        """Show the shop floor's disturbances (``drivers.sim.disturb``; ``Disturbances()`` for
        none) from the next frame rendered on; a replay ring is rendered again."""
        renderer = ShaftRenderer(self.settings.rig.with_(disturbances=spec),
                                 seed=self.settings.seed)
        with self._lock:
            self.settings.rig = renderer.config
            self.renderer = renderer
        if self._ring is not None:
            self._ring.set_renderer(renderer)

    def set_cnc_total(self, total_mm: float) -> None:
        """The virtual lathe's CNC holds a total wear offset of ``total_mm`` (mm of diameter)
        from now on (``CameraLathe.set_total``)."""
        if self.lathe is None:
            raise ValueError("no virtual lathe: start the camera with one (--lathe) to give "
                             "it the CNC's offset")
        self.lathe.set_total(total_mm)

    def set_turning(self, turning: Turning, spindle_deg_per_frame: float) -> None:
        """Show a surface off the spindle axis or out of round (``Turning()``: none), frame
        ``n`` at spindle angle ``n * spindle_deg_per_frame`` (as an encoder-triggered camera
        sees it); a replay ring is rendered again, and must hold whole revolutions."""
        if self._ring is not None and turning:
            self._ring.check_revolutions(spindle_deg_per_frame)
        renderer = ShaftRenderer(self.settings.rig.with_(turning=turning),
                                 seed=self.settings.seed)
        with self._lock:
            self.settings.rig = renderer.config
            self.settings.spindle_deg_per_frame = float(spindle_deg_per_frame)
            self.renderer = renderer
        if self._ring is not None:
            self._ring.spindle_step_deg = float(spindle_deg_per_frame)
            self._ring.set_renderer(renderer)

    def current_diameter(self) -> float:
        """The diameter being rendered now, mm (with the drift so far, or as the virtual
        lathe cut it)."""
        if self.lathe is not None:
            return self.lathe.diameter_mm()
        with self._lock:
            if self.settings.stepped is not None and self.stepped is not None:
                return self.stepped.diameter_mm(time.monotonic() - self._t0)
            minutes = (time.monotonic() - self._t0) / 60.0
            if self.settings.drift_period_min > 0:
                minutes %= self.settings.drift_period_min
            return self._d0 + self.settings.drift_um_per_min * minutes / 1000.0

    def show_board(self, shot: Shot | None, board: Board | None = None) -> None:
        """Show the calibration board as ``shot`` sets it up (None: back to the shaft). Frames
        rendered from the next one on show it."""
        with self._lock:
            self._scene = None if shot is None else (shot, board or Board(11, 8, 8.0))

    def scene(self) -> str:
        """What the camera shows: ``shaft`` or the board shot's name."""
        with self._lock:
            return "shaft" if self._scene is None else self._scene[0].name

    def set_lost_ratio(self, ratio: float) -> None:
        """Fraction of GVSP packets the camera drops (0 to 1)."""
        if not 0.0 <= ratio <= 1.0:
            raise ValueError("lost ratio must be within [0, 1]")
        self.settings.lost_ratio = ratio
        if self._gv:
            self._gobject.g_object_set(c_void_p(self._gv), b"gvsp-lost-ratio", c_double(ratio),
                                       None)

    def set_fps(self, fps: float) -> None:
        """Free-running frame rate (clients can change it too, through GenICam)."""
        if not 0.1 <= fps <= 1000:
            raise ValueError("fps must be within [0.1, 1000]")
        self.settings.fps = fps
        if self._gv:
            period = round(1e6 / fps)
            fake = self._lib.arv_gv_fake_camera_get_fake_camera(self._gv)
            self._lib.arv_fake_camera_write_register(fake, _REG_FRAME_PERIOD_US, period)
            self._requested_period_us = self._written_period_us = period
            self._clamp_frame_period()

    def stats(self) -> dict[str, float]:
        """Frames rendered (the stamp counter of the next frame) and sent, frames sent again
        because the renderer was behind, the current diameter."""
        x, y, w, h = self.region()
        return {"rendered": self._counter, "sent": self._sent, "repeats": self._repeats,
                "diameter_mm": round(self.current_diameter(), 7),
                "lost_ratio": self.settings.lost_ratio, "fps": self.settings.fps,
                "scene": self.scene(), "region": [x, y, w, h],
                "frame_period_us": self._written_period_us,
                "replay_frames": self.settings.replay_frames,
                "disturbances": bool(self.settings.rig.disturbances),
                "eccentricity_mm": self.settings.rig.turning.eccentricity_mm,
                "rerendered": self._ring.rerendered if self._ring else 0,
                "lathe": None if self.lathe is None else self.lathe.stats(),
                "stepped": None if self.stepped is None else self.stepped.stats()}

    # ---- sensor -------------------------------------------------------------------------

    def _register(self, address: int) -> int:
        value = c_uint32(0)
        if self._gv:
            fake = self._lib.arv_gv_fake_camera_get_fake_camera(self._gv)
            self._lib.arv_fake_camera_read_register(fake, address, byref(value))
        return int(value.value)

    def region(self) -> tuple[int, int, int, int]:
        """The sensor region clients set: (OffsetX, OffsetY, Width, Height), px."""
        if not self._gv:
            w, h = self.settings.rig.image_size
            return 0, 0, w, h
        return (self._register(_REG_OFFSET_X), self._register(_REG_OFFSET_Y),
                self._register(_REG_WIDTH), self._register(_REG_HEIGHT))

    def _clamp_frame_period(self) -> None:
        """Keep the frame period no shorter than the sensor's readout of the current rows
        (a client's new frame rate is taken as asked, then clamped)."""
        if not self._gv:
            return
        current = self._register(_REG_FRAME_PERIOD_US)
        if current != self._written_period_us:  # written by a client since
            self._requested_period_us = current
        period = max(self._requested_period_us, min_frame_period_us(self._register(_REG_HEIGHT)))
        if period != current:
            fake = self._lib.arv_gv_fake_camera_get_fake_camera(self._gv)
            self._lib.arv_fake_camera_write_register(fake, _REG_FRAME_PERIOD_US, period)
        self._written_period_us = period

    # ---- frames --------------------------------------------------------------------------

    def _render_next(self) -> np.ndarray:
        with self._lock:
            scene = self._scene
        if scene is None:
            image = self.renderer.render(
                self.current_diameter(), self._counter,
                spindle_deg=self._counter * self.settings.spindle_deg_per_frame)
        else:  # a still board: render it once, send copies
            if self._scene_image is None or self._scene_image[0] != scene:
                shot, board = scene
                br = BoardRenderer(self.renderer, board)
                self._scene_image = (scene, br.render(shot.pose(br), laser=shot.laser,
                                                      frame_index=shot.frame_index))
            image = self._scene_image[1].copy()
        stamp_frame(image, self._counter)
        self._counter += 1
        return image

    def _render_loop(self) -> None:
        while not self._stop.is_set():
            wanted = self._want.wait(0.05)
            self._clamp_frame_period()
            if self._stop.is_set():
                break
            if self._ring is not None and self.scene() == "shaft":
                self._ring.refresh(self._stop)
                self._want.clear()
                continue
            if not wanted:
                continue
            self._want.clear()
            image = self._render_next()
            with self._lock:
                self._ready = image

    def _fill(self, buffer: int, _data: int, _exposure: int, _gain: int, fmt: int) -> None:
        """Called by Aravis's streaming thread for every frame: copy the frame to send into
        the buffer, cut to the sensor region (8-bit, or scaled to 16 bits when the client
        chose a 16-bit pixel format), and its stamp over its first bytes."""
        try:
            image, stamped = self._frame_to_send()
            if image is None:
                return
            size = c_size_t(0)
            ptr = self._lib.arv_buffer_get_data(buffer, byref(size))
            if ptr:
                if (fmt >> 16) & 0xFF == 16:
                    if stamped:
                        image = image.copy()
                        image.reshape(-1)[:STAMP_BYTES] = np.frombuffer(stamped, np.uint8)
                    image = image.astype("<u2") * 257
                    ctypes.memmove(ptr, image.ctypes.data, image.nbytes)
                else:
                    ctypes.memmove(ptr, image.ctypes.data, image.nbytes)
                    if stamped:  # written into the buffer: the ring's frame is not copied
                        ctypes.memmove(ptr, stamped, STAMP_BYTES)
            self._sent += 1
        except Exception:  # pragma: no cover - never let an exception into C
            log.exception("fill callback")

    def _frame_to_send(self) -> tuple[np.ndarray | None, bytes]:
        """The next frame, cut to the region, and the stamp to send over its first bytes
        (empty when the frame carries its own)."""
        x, y, w, h = self.region()
        full = (x, y, w, h) == (0, 0, *self.settings.rig.image_size)
        if self._ring is not None and self.scene() == "shaft":
            image, slot = self._ring.take()
            out = image if full else crop(image, x, y, w, h)
            crc = self._ring.full_crc(slot, image) if full else None
            counter, self._counter = self._counter, self._counter + 1
            return out, stamp(counter, out, crc)
        with self._lock:
            image = self._ready
            fresh = image is not None and image.flags.writeable
            if image is not None:
                image.flags.writeable = False  # mark as sent
        if image is None:
            return None, b""
        if fresh:
            self._want.set()  # render the next one; never overwrite an unsent frame
        else:
            self._repeats += 1
        if full:
            return image, b""
        out = crop(image, x, y, w, h)
        return out, stamp(int.from_bytes(image.reshape(-1)[:8].tobytes(), "little"), out)
