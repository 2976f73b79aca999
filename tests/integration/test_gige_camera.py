"""The Aravis driver against the simulated camera over real GigE Vision on 127.0.0.1."""

from __future__ import annotations

import json
import os
import subprocess
import threading
import time

import numpy as np
import pytest

from calib_store.model import load_calibration
from drivers.camera.aravis import AravisCamera
from drivers.camera.base import CameraConfig, CameraState
from drivers.sim.control import control
from drivers.sim.gige import check_stamp
from service.measure.diameter import measure_frame
from service.measure.geometry import geometry_of
from tests.integration.conftest import SHAFTGAUGE, take_frames
from tests.waiting import DEADLINE_S


def wait_for(predicate, timeout_s: float, step_s: float = 0.1) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(step_s)
    return False


def native_threads() -> int:
    return len(os.listdir("/proc/self/task"))


@pytest.mark.parametrize("packet_socket", [True, False], ids=["packet-socket", "udp-socket"])
def test_streamed_frames_measure_to_the_simulated_diameter(sim_camera_factory,
                                                           packet_socket) -> None:
    sim = sim_camera_factory("MEAS01", diameter=34.924, fps=15.0)
    geometry = geometry_of(load_calibration(sim.calibration))
    cam = AravisCamera(sim.device_id, CameraConfig(packet_size=8192, frame_rate_hz=15.0,
                                                   packet_socket=packet_socket))
    cam.start()
    try:
        frames = take_frames(cam, 4)
    finally:
        cam.stop()
    assert len(frames) == 4
    errors = []
    for f in frames:
        assert f.image.shape == (1024, 1376)
        assert check_stamp(f.image)[1], "frame content differs from what the camera sent"
        m = measure_frame(f.image, geometry)
        assert m, m.reason
        errors.append(m.diameter_mm - 34.924)
    assert np.mean(np.abs(errors)) < 0.04, errors


def test_diameter_change_and_drift_reach_the_frames(sim_camera_factory) -> None:
    sim = sim_camera_factory("DRIFT1", diameter=25.0, fps=15.0)
    geometry = geometry_of(load_calibration(sim.calibration))
    cam = AravisCamera(sim.device_id, CameraConfig(packet_size=8192))
    cam.start()
    try:
        before = measure_frame(take_frames(cam, 1)[0].image, geometry)
        reply = control(sim.control_port, {"set": {"diameter_mm": 40.0}})
        assert reply["ok"] and reply["stats"]["diameter_mm"] == pytest.approx(40.0, abs=1e-6)
        first_new = reply["stats"]["rendered"] + 1  # a frame already rendered may be queued
        frame = None
        while frame is None or check_stamp(frame.image)[0] < first_new:
            frame = take_frames(cam, 1)[0]
        after = measure_frame(frame.image, geometry)
    finally:
        cam.stop()
    assert before and abs(before.diameter_mm - 25.0) < 0.08
    assert after and abs(after.diameter_mm - 40.0) < 0.08
    bad = control(sim.control_port, {"set": {"colour": 3}})
    assert not bad["ok"] and "unknown" in bad["error"]


def test_camera_killed_and_restarted_reconnects_by_itself(sim_camera_factory) -> None:
    errors: list = []
    old_hook = threading.excepthook
    threading.excepthook = lambda args: errors.append(args)
    baseline = native_threads()
    sim = sim_camera_factory("KILL01", fps=20.0)
    cam = AravisCamera(sim.device_id, CameraConfig(packet_size=8192,
                                                   reconnect_initial_s=0.2,
                                                   reconnect_max_s=1.0))
    try:
        cam.start()
        assert len(take_frames(cam, 3)) == 3
        sim.kill()
        assert wait_for(lambda: cam.status().state in (CameraState.LOST,
                                                       CameraState.RECONNECTING), 15), \
            cam.status()
        assert "KILL01" in cam.status().message
        while cam.get_frame(0) is not None:  # drain what came before the loss
            pass
        sim.start()
        assert wait_for(lambda: cam.status().state is CameraState.STREAMING, 30), cam.status()
        frames = take_frames(cam, 3)
        assert len(frames) == 3
        assert cam.status().counters.reconnects == 1
    finally:
        cam.stop()
        threading.excepthook = old_hook
    assert not errors, errors
    assert not [t for t in threading.enumerate() if t.name.startswith("camera:")]
    # Aravis's own stream and heartbeat threads end with their objects.
    assert wait_for(lambda: native_threads() <= baseline + 1, 10), (native_threads(), baseline)


def test_missing_camera_is_reported_and_retried_not_raised() -> None:
    cam = AravisCamera("Nobody-Here-0", CameraConfig(reconnect_initial_s=0.1,
                                                     reconnect_max_s=0.2))
    cam.start()
    try:
        assert wait_for(lambda: "cannot open" in cam.status().message, 10), cam.status()
        assert cam.status().state is CameraState.CONNECTING
        assert cam.get_frame(0.3) is None
    finally:
        cam.stop()


def test_packet_loss_counts_incomplete_frames_and_never_delivers_them(sim_camera_factory):
    sim = sim_camera_factory("LOSS01", fps=25.0, extra=("--lost-ratio", "0.004"))
    cam = AravisCamera(sim.device_id, CameraConfig(packet_size=8192, queue_size=64))
    cam.start()
    try:
        frames = take_frames(cam, 25, timeout_s=30)
        st = cam.status()
    finally:
        cam.stop()
    assert len(frames) == 25
    assert all(check_stamp(f.image)[1] for f in frames), "an incomplete frame was delivered"
    assert st.counters.failed > 0, st
    assert st.counters.missing_packets > 0, st


def test_camera_list_and_grab_commands(sim_camera_factory, tmp_path) -> None:
    sim = sim_camera_factory("CLI001", fps=15.0)
    listed = subprocess.run([SHAFTGAUGE, "camera", "list"], capture_output=True, text=True,
                            timeout=60)
    assert listed.returncode == 0
    devices = [json.loads(line) for line in listed.stdout.splitlines()]
    mine = [d for d in devices if d["device_id"] == sim.device_id]
    assert mine and mine[0]["address"] == "127.0.0.1" and mine[0]["vendor"] == "Aravis"
    grab = subprocess.run([SHAFTGAUGE, "camera", "grab", sim.device_id, "--count", "3",
                           "--output", str(tmp_path / "g"), "--packet-size", "8192"],
                          capture_output=True, text=True, timeout=60)
    assert grab.returncode == 0, grab.stderr
    report = json.loads(grab.stdout)
    assert report["saved"] == 3 and report["counters"]["completed"] >= 3
    assert len(list((tmp_path / "g").glob("*.png"))) == 3
    missing = subprocess.run([SHAFTGAUGE, "camera", "grab", "Nobody-0", "--count", "1",
                              "--output", str(tmp_path / "n"), "--timeout", "2"],
                             capture_output=True, text=True, timeout=60)
    assert missing.returncode == 2 and "Nobody-0" in missing.stderr


def test_a_client_killed_while_streaming_leaves_the_camera_usable(sim_camera_factory,
                                                                   tmp_path) -> None:
    """A service killed (-9) while it streams leaves the camera acquiring towards its dead
    address: the next client stops that acquisition before setting its own, and streams
    with no reconnect (it used to wait forever on a silent stream, then reconnect)."""
    cam = sim_camera_factory("KILLED1")
    grab = subprocess.Popen([SHAFTGAUGE, "camera", "grab", cam.device_id, "--count", "100000",
                             "--output", str(tmp_path / "frames"), "--timeout", "60"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        assert wait_for(lambda: len(list((tmp_path / "frames").glob("*.png"))) >= 3, 30)
    finally:
        grab.kill()
        grab.wait(10)
    camera = AravisCamera(cam.device_id, CameraConfig(frame_rate_hz=10.0))
    camera.start()
    try:
        frames = take_frames(camera, 3, timeout_s=DEADLINE_S)
        assert len(frames) == 3, camera.status()
        assert camera.status().counters.reconnects == 0, camera.status()
    finally:
        camera.stop()
