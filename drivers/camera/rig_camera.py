"""A simulated camera without any network: the rig's renderer behind the ``Camera`` interface.

For unit tests of consumers (the pipeline) and for machines without Aravis. It honours the
frame rate, the trigger mode (``software``: one frame per trigger), Mono8 or Mono16 frames,
a region of interest (``set_region``), and can be told to vanish and come back (``unplug`` /
``plug``) to exercise loss handling.

With ``replay_frames`` it renders each of that many frames once per diameter (frame ``k`` is
slot ``k % replay_frames``, rendered when first sent and again when ``diameter_mm`` has
changed since) and then sends it again: rendering costs tens of milliseconds a frame, about
two thirds of a core at 20 frames/s, which a test of the gauge's consumers does not need to
pay for every frame.
"""

from __future__ import annotations

import threading
import time

import numpy as np

from drivers.camera.base import (
    NO_REGION_REQUEST,
    CameraConfig,
    CameraError,
    CameraState,
    Frame,
    ThreadedCamera,
)
from drivers.sim.rig import RigConfig, ShaftRenderer


class RigCamera(ThreadedCamera):
    """Renders the simulated rig's frames at ``config.frame_rate_hz`` in its own thread."""

    def __init__(self, diameter_mm: float = 30.0, config: CameraConfig | None = None,
                 rig: RigConfig | None = None, seed: int = 0,
                 device_id: str = "sim-rig", replay_frames: int = 0) -> None:
        super().__init__(device_id, config or CameraConfig(frame_rate_hz=10.0))
        self.renderer = ShaftRenderer(rig or RigConfig(), seed=seed)
        self.diameter_mm = diameter_mm
        self.replay_frames = max(0, int(replay_frames))
        self._ring: dict[int, tuple[float, np.ndarray]] = {}  # slot -> (diameter, frame)
        self._trigger = threading.Semaphore(0)
        self._plugged = threading.Event()
        self._plugged.set()
        self._frame_id = 0
        self._region: tuple[int, int, int, int] | None = config.region if config else None

    def _wake(self) -> None:
        self._trigger.release()

    def software_trigger(self) -> None:
        if self.config.trigger != "software":
            raise CameraError(f"{self.device_id}: trigger mode is {self.config.trigger}")
        self._trigger.release()

    def unplug(self) -> None:
        """Simulate the camera vanishing: no frames, state LOST, until ``plug``."""
        self._plugged.clear()

    def plug(self) -> None:
        """Bring the camera back."""
        self._plugged.set()

    def _fit_region(self, region: tuple[int, int, int, int] | None
                    ) -> tuple[int, int, int, int] | None:
        """The region clipped to the sensor (None: the whole sensor)."""
        if region is None:
            return None
        sw, sh = self.renderer.config.image_size
        x, y = min(region[0], sw - 1), min(region[1], sh - 1)
        return x, y, min(region[2], sw - x), min(region[3], sh - y)

    def _run(self) -> None:
        period = 1.0 / (self.config.frame_rate_hz or 10.0)
        next_t = time.monotonic()
        self._set_state(CameraState.STREAMING, "streaming (simulated rig)")
        while not self._stop.is_set():
            if not self._plugged.is_set():
                self._set_state(CameraState.LOST, f"camera {self.device_id} lost (unplugged)")
                while not self._plugged.wait(0.05):
                    if self._stop.is_set():
                        return
                with self._lock:
                    self._counters.reconnects += 1
                self._set_state(CameraState.STREAMING, "streaming (simulated rig)")
            if self.config.trigger == "software":
                if not self._trigger.acquire(timeout=0.1) or self._stop.is_set():
                    continue
            else:
                delay = next_t - time.monotonic()
                if delay > 0 and self._stop.wait(delay):
                    break
                next_t = max(next_t + period, time.monotonic() - period)
            request = self._take_region_request()
            if request is not NO_REGION_REQUEST:
                self._region = self._fit_region(request)  # type: ignore[arg-type]
                self._region_applied(self._region)
            image = self._image(self._frame_id)
            origin = None
            if self._region is not None:
                x, y, w, h = self._region
                image, origin = np.ascontiguousarray(image[y:y + h, x:x + w]), (x, y)
            if self.config.pixel_format in ("Mono12", "Mono16"):
                image = image.astype(np.uint16) * np.uint16(257)
            frame = Frame(image, self._frame_id, time.monotonic_ns(), time.monotonic_ns(),
                          origin)
            self._frame_id += 1
            self._deliver(frame)

    def _image(self, frame_id: int) -> np.ndarray:
        """The full-sensor frame ``frame_id`` at the current diameter (not to be written to)."""
        diameter = self.diameter_mm
        if not self.replay_frames:
            return self.renderer.render(diameter, frame_id)
        slot = frame_id % self.replay_frames
        held = self._ring.get(slot)
        if held is None or held[0] != diameter:
            image = self.renderer.render(diameter, frame_id)
            image.flags.writeable = False
            held = self._ring[slot] = (diameter, image)
        return held[1]
