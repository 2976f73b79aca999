"""One suite over every camera implementation: Aravis over real GigE Vision to the simulated
camera (with and without Aravis's packet socket), Aravis's in-process fake, and the pure-Python
simulated rig camera."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator

import numpy as np
import pytest

from drivers.camera.aravis import AravisCamera, enable_fake_interface
from drivers.camera.base import Camera, CameraConfig, CameraState
from drivers.camera.rig_camera import RigCamera
from tests.integration.conftest import take_frames
from tests.waiting import until

IMPLEMENTATIONS = ["gige-sim", "gige-sim-udp", "aravis-fake", "rig"]


@pytest.fixture(params=IMPLEMENTATIONS)
def make_camera(request, sim_camera_factory) -> Iterator:
    kind = request.param
    made: list[Camera] = []

    def make(**kw) -> Camera:
        cfg = CameraConfig(**{"frame_rate_hz": 20.0, **kw})
        if kind.startswith("gige-sim"):
            if not hasattr(make, "sim"):
                make.sim = sim_camera_factory("CONTRACT", fps=20.0)
            if kind == "gige-sim-udp":
                cfg = CameraConfig(**{**cfg.__dict__, "packet_socket": False})
            cam: Camera = AravisCamera(make.sim.device_id, cfg)
        elif kind == "aravis-fake":
            enable_fake_interface()
            cam = AravisCamera("Fake_1", cfg)
        else:
            cam = RigCamera(25.0, cfg)
        made.append(cam)
        return cam

    make.kind = kind
    yield make
    for cam in made:
        cam.stop()


def test_frames_arrive_complete_and_in_order(make_camera) -> None:
    cam = make_camera()
    cam.start()
    frames = take_frames(cam, 5)
    assert len(frames) == 5, cam.status()
    ids = [f.frame_id for f in frames]
    assert ids == sorted(ids) and len(set(ids)) == 5
    for f in frames:
        assert f.image.dtype == np.uint8 and f.image.ndim == 2 and f.image.size > 0
        assert f.received_ns > 0
    st = cam.status()
    assert st.state is CameraState.STREAMING
    assert st.counters.completed >= 5


def test_mono16_gives_uint16_frames(make_camera) -> None:
    cam = make_camera(pixel_format="Mono16")
    cam.start()
    frames = take_frames(cam, 2)
    assert len(frames) == 2, cam.status()
    assert all(f.image.dtype == np.uint16 for f in frames)
    assert max(int(f.image.max()) for f in frames) > 255  # really 16-bit data


def test_slow_consumer_drops_oldest_and_counts(make_camera) -> None:
    cam = make_camera(queue_size=2)
    cam.start()
    take_frames(cam, 1)
    # Nobody takes a frame while eight arrive (however long a loaded machine takes to make
    # them): one taken, two queued, five dropped at least.
    until(lambda: cam.status().counters.completed >= 8, "eight frames arrived")
    first = cam.get_frame(1.0)
    st = cam.status()
    assert st.counters.dropped >= 5, st
    later = take_frames(cam, 1)[0]
    assert later.frame_id > first.frame_id


def test_stop_ends_the_thread_and_restart_works(make_camera) -> None:
    before = {t.name for t in threading.enumerate()}
    cam = make_camera()
    cam.start()
    cam.start()  # idempotent
    assert take_frames(cam, 2)
    cam.stop()
    cam.stop()
    assert cam.status().state is CameraState.STOPPED
    leftover = {t.name for t in threading.enumerate()} - before
    assert not [n for n in leftover if n.startswith("camera:")]
    while cam.get_frame(0) is not None:  # what was queued before the stop
        pass
    assert cam.get_frame(0.2) is None
    cam.start()
    assert take_frames(cam, 2)


def test_software_trigger_gives_one_frame_per_trigger(make_camera) -> None:
    if make_camera.kind.startswith("gige-sim"):
        pytest.skip("the simulated GigE camera free-runs (Aravis's GV fake has no trigger)")
    cam = make_camera(trigger="software")
    cam.start()
    assert cam.get_frame(0.8) is None  # nothing without a trigger
    deadline = time.monotonic() + 10
    while cam.status().state is not CameraState.STREAMING and time.monotonic() < deadline:
        time.sleep(0.05)
    for _ in range(3):
        cam.software_trigger()
        assert cam.get_frame(5.0) is not None


def test_a_region_of_interest_is_read_and_the_whole_sensor_again(make_camera) -> None:
    cam = make_camera()
    cam.start()
    cam.set_region(None)  # Aravis's fake starts on a 512x512 region of a larger sensor
    whole = [f for f in take_frames(cam, 40) if f.origin is None][-1]
    assert cam.status().region is None
    h, w = whole.image.shape
    cam.set_region((64, 32, 200, 120))
    frames = take_frames(cam, 40)
    region = [f for f in frames if f.origin is not None]
    assert region, cam.status()
    f = region[-1]
    # The camera rounds to its increments; the frame says what it read.
    assert f.origin == (64, 32) and f.image.shape == (120, 200), (f.origin, f.image.shape)
    assert cam.status().region == (64, 32, 200, 120)
    assert frames[-1].origin is not None  # every frame after the change is a region
    cam.set_region(None)
    back = [f for f in take_frames(cam, 40) if f.origin is None]
    assert back and back[-1].image.shape == (h, w)
    assert cam.status().region is None and cam.status().counters.region_changes >= 2
