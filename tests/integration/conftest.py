"""Real peers on loopback: a simulated GigE Vision camera in its own process."""

from __future__ import annotations

import contextlib
import json
import subprocess
import sys
import time
from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from tests.processes import end_group
from tests.unit.service.conftest import client  # noqa: F401 (the API on simulated parts)

SHAFTGAUGE = str(Path(sys.executable).with_name("shaftgauge"))


@dataclass
class SimCameraProcess:
    """A running ``shaftgauge sim-camera``."""

    args: list[str]
    calibration: Path
    proc: subprocess.Popen | None = None
    device_id: str = ""
    control_port: int = 0

    def start(self, timeout_s: float = 30.0) -> SimCameraProcess:
        self.proc = subprocess.Popen(self.args, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     text=True, start_new_session=True)
        deadline = time.monotonic() + timeout_s
        line = ""
        while time.monotonic() < deadline and not line:
            line = self.proc.stdout.readline()
            if self.proc.poll() is not None:
                raise RuntimeError(f"sim-camera exited: {self.proc.stderr.read()}")
        ready = json.loads(line)
        assert ready["event"] == "ready"
        self.device_id, self.control_port = ready["device_id"], ready["control_port"]
        return self

    def kill(self) -> None:
        """Vanish at once, as a camera whose cable is pulled."""
        if self.proc:
            end_group(self.proc)

    def stop(self) -> None:
        if self.proc:
            end_group(self.proc, term_wait_s=10)


def sim_camera_process(tmp: Path, serial: str, diameter: float = 30.0, fps: float = 10.0,
                       extra: tuple[str, ...] = ()) -> SimCameraProcess:
    cal = tmp / f"{serial}.json"
    args = [SHAFTGAUGE, "sim-camera", "--serial", serial, "--address", "127.0.0.1",
            "--diameter", str(diameter), "--fps", str(fps), "--calibration-out", str(cal),
            "--seed", "5", *extra]
    return SimCameraProcess(args, cal)


@pytest.fixture
def sim_camera_factory(tmp_path) -> Iterator:
    """Start simulated cameras (one at a time on 127.0.0.1); all are stopped afterwards."""
    started: list[SimCameraProcess] = []

    def make(serial: str = "TEST01", **kw) -> SimCameraProcess:
        cam = sim_camera_process(tmp_path, serial, **kw).start()
        started.append(cam)
        return cam

    yield make
    for cam in started:
        cam.stop()


def take_frames(camera, n: int, timeout_s: float = 20.0) -> list:
    """Up to ``n`` frames from a camera within ``timeout_s``."""
    frames, deadline = [], time.monotonic() + timeout_s
    while len(frames) < n and time.monotonic() < deadline:
        f = camera.get_frame(0.5)
        if f is not None:
            frames.append(f)
    return frames


_GIVEN: deque[int] = deque(maxlen=256)


def free_port() -> int:
    """A TCP port free on 127.0.0.1 right now, and none that this process gave out lately: the
    kernel may hand the same free port to two calls in a row (a clean-clone run gave a
    service's REST and Modbus servers one port, as neither was bound yet)."""
    import socket

    while True:
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            port = s.getsockname()[1]
        if port not in _GIVEN:
            _GIVEN.append(port)
            return port


@dataclass
class SimPlcProcess:
    """A running ``shaftgauge sim-plc``."""

    args: list[str]
    port: int
    proc: subprocess.Popen | None = None

    def start(self) -> SimPlcProcess:
        self.proc = subprocess.Popen(self.args, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     text=True, start_new_session=True)
        line = self.proc.stdout.readline()
        if not line:
            raise RuntimeError(f"sim-plc exited: {self.proc.stderr.read()}")
        assert json.loads(line)["port"] == self.port
        return self

    def kill(self) -> None:
        if self.proc:
            end_group(self.proc)

    def stop(self) -> None:
        if self.proc:
            end_group(self.proc, term_wait_s=10)


@pytest.fixture
def sim_plc_factory(tmp_path) -> Iterator:
    """Start simulated PLC processes on free ports; all are stopped afterwards."""
    started: list[SimPlcProcess] = []

    def make(port: int | None = None, *extra: str) -> SimPlcProcess:
        port = port or free_port()
        plc = SimPlcProcess([SHAFTGAUGE, "sim-plc", "--port", str(port), "--log",
                             str(tmp_path / "plc.log"), "--state",
                             str(tmp_path / "plc.state"), *extra], port).start()
        started.append(plc)
        return plc

    make.log = tmp_path / "plc.log"
    yield make
    for plc in started:
        plc.stop()


@dataclass
class SmallDisk:
    """A 2 MiB tmpfs mounted for one test: ``fill()`` leaves it with no free space, ``free()``
    gives the space back."""

    path: Path

    def fill(self) -> None:
        with contextlib.suppress(OSError), open(self.path / "filler", "wb") as f:
            while True:
                f.write(b"\0" * 4096)
                f.flush()

    def free(self) -> None:
        (self.path / "filler").unlink(missing_ok=True)

    def read_only(self) -> None:
        subprocess.run(["mount", "-o", "remount,ro", str(self.path)], check=True)


@pytest.fixture
def small_disk(tmp_path) -> Iterator[SmallDisk]:
    """A real full-disk condition under a store (needs root to mount a tmpfs, as in CI)."""
    mnt = tmp_path / "small-disk"
    mnt.mkdir()
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=2m", "tmpfs", str(mnt)],
                       capture_output=True, text=True)
    if r.returncode != 0:
        pytest.fail(f"cannot mount a tmpfs for the full-disk test (run as root): {r.stderr}")
    try:
        yield SmallDisk(mnt)
    finally:
        subprocess.run(["umount", "-l", str(mnt)], check=False)
