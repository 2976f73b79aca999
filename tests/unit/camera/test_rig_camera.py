"""The in-process simulated rig camera's replay ring."""

from __future__ import annotations

import numpy as np

from drivers.camera.base import CameraConfig, Frame
from drivers.camera.rig_camera import RigCamera


def _frames(cam: RigCamera, n: int) -> list[Frame]:
    out = []
    while len(out) < n:
        frame = cam.get_frame(10.0)
        assert frame is not None, "the rig camera sent no frame"
        out.append(frame)
    return out


def test_a_ring_sends_each_slot_again_and_shows_a_new_diameter_at_once() -> None:
    # Slots by frame number: a busy machine may drop frames from the queue between two.
    cam = RigCamera(30.0, CameraConfig(frame_rate_hz=50.0, queue_size=1), replay_frames=3)
    cam.start()
    try:
        old = {}
        for f in _frames(cam, 12):
            slot = f.frame_id % 3
            if slot in old:  # the same frame a ring later
                assert np.array_equal(old[slot], f.image), f.frame_id
            old[slot] = f.image
        assert len(old) == 3
        assert not np.array_equal(old[0], old[1])  # fresh speckle in each slot
        cam.diameter_mm = 40.0
        after = _frames(cam, 5)
        # At most the frame in the queue and the one being made show the old diameter.
        changed = [not np.array_equal(f.image, old[f.frame_id % 3]) for f in after]
        assert all(changed[2:]), changed
        assert not after[-1].image.flags.writeable
    finally:
        cam.stop()


def test_without_a_ring_every_frame_is_rendered() -> None:
    cam = RigCamera(30.0, CameraConfig(frame_rate_hz=100.0))
    cam.start()
    try:
        frames = [f.image for f in _frames(cam, 4)]
        assert not any(np.array_equal(frames[0], f) for f in frames[1:])
    finally:
        cam.stop()
