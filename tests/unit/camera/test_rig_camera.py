"""The in-process simulated rig camera's replay ring."""

from __future__ import annotations

import numpy as np

from drivers.camera.base import CameraConfig
from drivers.camera.rig import RigCamera


def _frames(cam: RigCamera, n: int) -> list[np.ndarray]:
    out = []
    while len(out) < n:
        frame = cam.get_frame(2.0)
        assert frame is not None, "the rig camera sent no frame"
        out.append(frame.image)
    return out


def test_a_ring_sends_each_slot_again_and_shows_a_new_diameter_at_once() -> None:
    cam = RigCamera(30.0, CameraConfig(frame_rate_hz=100.0), replay_frames=3)
    cam.start()
    try:
        first = _frames(cam, 6)
        # Fresh speckle in each slot, the same frame a ring later.
        assert not np.array_equal(first[0], first[1])
        assert all(np.array_equal(first[k], first[k + 3]) for k in range(3))
        cam.diameter_mm = 40.0
        after = _frames(cam, 4)
        # At most the frame already taken from the renderer shows the old diameter.
        changed = [not any(np.array_equal(a, f) for f in first) for a in after]
        assert all(changed[1:]), changed
        assert not after[-1].flags.writeable
    finally:
        cam.stop()


def test_without_a_ring_every_frame_is_rendered() -> None:
    cam = RigCamera(30.0, CameraConfig(frame_rate_hz=100.0))
    cam.start()
    try:
        frames = _frames(cam, 4)
        assert not any(np.array_equal(frames[0], f) for f in frames[1:])
    finally:
        cam.stop()
