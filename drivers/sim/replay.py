"""A ring of pre-rendered frames for the simulated camera, and the sensor's region of interest.

Rendering a frame of the simulated rig costs tens of milliseconds of CPU: a simulated camera
that renders every frame it sends steals the gauge's CPU in a benchmark. In replay mode it
renders ``size`` frames at start (fresh speckle in each, as the shaft turns) and then only
sends them in turn; when the diameter changes (a jump, or the tool-wear drift) the frames
that show an old diameter are rendered again in the background, one at a time, so the
diameter and the drift stay changeable. The diameter shown moves in steps (a quarter of a
micrometre by default, a fifth of what one frame resolves): a slow drift then costs a ring's
rendering every step (0.4 um a minute: 32 frames every 37 s, about 2 % of a core), not
every frame's, and the stripe's light is computed once a step for the whole ring.

``crop`` applies a GenICam region (``OffsetX``, ``OffsetY``, ``Width``, ``Height``) to a
full-sensor frame; ``min_frame_period_us`` is the sensor's readout time, which makes the frame
rate rise as rows are taken away, as a real CMOS sensor's does.
"""

from __future__ import annotations

import math
import threading
import time
import zlib
from collections.abc import Callable

import numpy as np

from drivers.sim.rig import ShaftRenderer

ROW_TIME_US = 6.0
"""Readout time of one sensor row, microseconds: 1024 rows take 6.1 ms (about 160 frames/s
at full height), 400 rows 2.4 ms (about 380 frames/s)."""
FRAME_OVERHEAD_US = 200.0
REST = 2.0
"""A ring rendered again for a drift's step rests twice as long as each frame took: a third
of a core."""
JUMP_MM = 1e-3
"""A change of the diameter larger than this is a jump, not a drift's step."""
PART_CHANGE_MM = 0.05
"""A jump larger than this is another part under the laser (a master put in, the next
segment of a stepped part): no frame sent may show the one before. Smaller ones (an offset
applied) are rendered again in the background, as a drift's step is, at full speed."""


def min_frame_period_us(height: int) -> int:
    """Shortest frame period (us) of a sensor reading ``height`` rows."""
    return round(max(1, height) * ROW_TIME_US + FRAME_OVERHEAD_US)


def crop(image: np.ndarray, offset_x: int, offset_y: int, width: int, height: int
         ) -> np.ndarray:
    """The region of ``image`` (a contiguous copy), clipped to the image."""
    h, w = image.shape[:2]
    x0, y0 = min(max(0, offset_x), w - 1), min(max(0, offset_y), h - 1)
    return np.ascontiguousarray(image[y0:min(h, y0 + max(1, height)),
                                      x0:min(w, x0 + max(1, width))])


class FrameRing:
    """Pre-rendered frames of the shaft, sent in turn.

    Parameters
    ----------
    renderer : ShaftRenderer
        The rig.
    size : int
        Frames in the ring.
    diameter_mm : callable
        The diameter to show now, mm (the camera's, with its drift).
    step_mm : float
        The diameter shown is the current one rounded to this step; a frame that shows
        another is rendered again.
    """

    def __init__(self, renderer: ShaftRenderer, size: int, diameter_mm: Callable[[], float],
                 step_mm: float = 2.5e-4) -> None:
        if size < 1:
            raise ValueError("a replay ring needs at least one frame")
        if not step_mm > 0:
            raise ValueError("the diameter's step must be positive")
        self.renderer, self.size = renderer, int(size)
        self._current, self._step = diameter_mm, float(step_mm)
        self._lock = threading.Lock()
        self._frames: list[np.ndarray] = []
        self._shown: list[float] = []
        self._crc: dict[int, int] = {}   # slot -> CRC-32 of its rows 1.. (full frame)
        self._next = 0
        self._rendered = 0
        self.rerendered = 0
        self.rest = REST
        self.spindle_step_deg = 0.0  # the spindle's turn from one frame to the next

    def _diameter(self) -> float:
        """The diameter to show now: the current one, to the step."""
        return round(self._current() / self._step) * self._step

    def fill(self) -> None:
        """Render every frame of the ring (at start)."""
        d = self._diameter()
        frames = [self._render(d, slot) for slot in range(self.size)]
        with self._lock:
            self._frames, self._shown, self._crc = frames, [d] * self.size, {}

    def refresh(self, stop: threading.Event) -> int:
        """Render again, one at a time, the frames that show an old diameter, starting with
        those to be sent next; returns how many (stops early when ``stop`` is set). A drift's
        step rests between two frames ``rest`` times as long as the last one took: the camera
        shares the gauge's cores, and a ring rendered at full speed took one of them for
        most of a second; a jump (more than ``JUMP_MM``) is rendered at full speed, so that
        it reaches the frames sent at once."""
        done = 0
        with self._lock:
            first = self._next + 1
        for k in range(self.size):
            slot = (first + k) % self.size
            if stop.is_set():
                break
            d = self._diameter()
            with self._lock:
                stale = self._shown[slot] != d
            if not stale:
                continue
            t0 = time.monotonic()
            with self._lock:
                jump = abs(self._shown[slot] - d) > JUMP_MM
            image = self._render(d, slot)
            with self._lock:
                self._frames[slot], self._shown[slot] = image, d
                self._crc.pop(slot, None)
            done += 1
            if not jump:
                stop.wait((time.monotonic() - t0) * self.rest)
        self.rerendered += done
        return done

    def check_revolutions(self, spindle_step_deg: float) -> None:
        """ValueError unless the ring holds whole revolutions at this step: frame ``n`` then
        shows the spindle at ``n * step`` however long the ring is replayed."""
        turns = self.size * spindle_step_deg / 360.0
        if abs(turns - round(turns)) > 1e-9:
            raise ValueError(
                f"spindle_deg_per_frame {spindle_step_deg:g} with a replay ring of {self.size} "
                f"frames: the ring must hold whole revolutions (a multiple of "
                f"{360.0 / self.size:g} degrees a frame), or start the camera with no ring")

    def set_renderer(self, renderer: ShaftRenderer) -> None:
        """Render with ``renderer`` from now on; every frame is rendered again (``refresh``),
        those to be sent next first."""
        with self._lock:
            self.renderer = renderer
            self._shown = [math.inf] * self.size

    def take(self) -> tuple[np.ndarray, int]:
        """The next frame to send (not to be written to) and its slot. A slot still showing
        another part (``PART_CHANGE_MM``, or the renderer before a change) is rendered now: a
        camera never shows the part that was in the lathe before, however slowly the ring
        is rendered again (the frame rate dips instead)."""
        d = self._diameter()
        with self._lock:
            slot = self._next
            self._next = (self._next + 1) % self.size
            if not abs(self._shown[slot] - d) > PART_CHANGE_MM:
                return self._frames[slot], slot
        image = self._render(d, slot)
        with self._lock:
            self._frames[slot], self._shown[slot] = image, d
            self._crc.pop(slot, None)
        return image, slot

    def full_crc(self, slot: int, image: np.ndarray) -> int:
        """CRC-32 of rows 1.. of a slot's full frame (computed once per rendering)."""
        with self._lock:
            crc = self._crc.get(slot)
        if crc is None:
            crc = zlib.crc32(image[1:].tobytes())
            with self._lock:
                self._crc[slot] = crc
        return crc

    def _render(self, diameter_mm: float, slot: int) -> np.ndarray:
        with self._lock:  # ``take`` and ``refresh`` render from two threads
            index, self._rendered = self._rendered, self._rendered + 1
        if self.spindle_step_deg:  # a turning surface: the slot's frames are at its angle
            return self.renderer.render(diameter_mm, index,
                                        spindle_deg=slot * self.spindle_step_deg)
        return self.renderer.render(diameter_mm, index)
