"""Shared fixtures: a simulated rig and its exact calibration, a rendered calibration set."""

from __future__ import annotations

import fcntl
import os
import subprocess
import sys
from pathlib import Path

import pytest

from drivers.sim.rig import RigConfig, ShaftRenderer

RIG_DIRS = ("tests/e2e/", "tests/faults/", "tests/integration/linuxcnc/")
RIG_MARKS = ("start_service", "sim_camera", "drivers.sim.gige", "drivers.camera.aravis",
             "test_speed_guard")
"""What needs the one simulated GigE camera's port (3956 on 127.0.0.1), LinuxCNC, or the
machine to itself (services timed against their baseline): those run one after another on
one worker of ``pytest -n`` (``xdist_group``); the rest share the other cores."""


_RIG: dict[Path, bool] = {}


def _needs_the_rig(path: Path) -> bool:
    if path not in _RIG:
        rel = path.relative_to(Path(__file__).resolve().parents[1]).as_posix()
        _RIG[path] = rel.startswith(RIG_DIRS) or any(
            mark in rel or mark in path.read_text() for mark in RIG_MARKS)
    return _RIG[path]


def pytest_itemcollected(item: pytest.Item) -> None:
    # As each test is collected: xdist reads the groups into the test ids after collection.
    if _needs_the_rig(Path(item.fspath)):
        item.add_marker(pytest.mark.xdist_group("rig"))


@pytest.fixture(scope="session")
def renderer() -> ShaftRenderer:
    """The default simulated rig (geometry like the reference paper's)."""
    return ShaftRenderer(RigConfig(), seed=7)


@pytest.fixture(scope="session")
def calibration_images(tmp_path_factory) -> Path:
    """A simulated calibration session's images, as ``shaftgauge calibrate render`` writes
    them (``views/``, ``plane/``, ``axis/``): rendered once for every test that only reads
    them (half a minute of rendering each time otherwise)."""
    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        root = root.parent  # shared by this run's workers: rendered once, not once each
    out = root / "calibration-images"
    with open(root / "calibration-images.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not (out / ".rendered").exists():
            shaftgauge = str(Path(sys.executable).with_name("shaftgauge"))
            r = subprocess.run([shaftgauge, "calibrate", "render", "--output", str(out)],
                               capture_output=True, text=True, timeout=300)
            assert r.returncode == 0, r.stderr
            (out / ".rendered").touch()
    return out
