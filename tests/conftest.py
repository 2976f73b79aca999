"""Shared fixtures: a simulated rig and its exact calibration, a rendered calibration set."""

from __future__ import annotations

import fcntl
import os
import subprocess
import sys
from collections import Counter
from pathlib import Path

import pytest

from drivers.sim.rig import RigConfig, ShaftRenderer
from tests import netns

RIG_DIRS = ("tests/e2e/", "tests/faults/", "tests/integration/linuxcnc/")
RIG_MARKS = ("start_service", "sim_camera", "drivers.sim.gige", "drivers.camera.aravis",
             "test_speed_guard")
"""What needs the simulated GigE camera's port (3956 on 127.0.0.1), LinuxCNC, or the machine
to itself (services timed against their baseline)."""
MACHINE_DIRS = ("tests/integration/linuxcnc/",)
MACHINE_MARKS = ("test_speed_guard",)
"""Of those, what no loopback of its own separates: LinuxCNC's realtime and shared memory
are the host's, and the timed services should not meet each other."""


def pytest_configure(config: pytest.Config) -> None:
    # The controller finds out once whether workers can each have a loopback of their own
    # (tests/netns.py) and tells them through the environment they inherit, so that every
    # worker groups the tests alike; SHAFTGAUGE_TEST_NETNS=0 keeps the host's for all.
    worker = os.environ.get("PYTEST_XDIST_WORKER")
    if worker is None and (config.getoption("numprocesses", None) or 0):
        if os.environ.get(netns.ENV) != "0":
            os.environ[netns.ENV] = "1" if netns.can_unshare() else "0"
    elif worker is not None and os.environ.get(netns.ENV) == "1":
        netns.enter_own_loopback()


_GROUP: dict[Path, str] = {}


def _group_of(path: Path) -> str:
    """The ``xdist_group`` a test file's tests run in: ``machine`` for what must run one after
    another (every rig test without loopbacks of their own), else the file's own group, so
    that a module's fixtures (a rendered session, a started service) are made once, not once
    on each worker that would take one of its tests."""
    if path not in _GROUP:
        rel = path.relative_to(Path(__file__).resolve().parents[1]).as_posix()
        rig = rel.startswith(RIG_DIRS) or any(m in rel or m in path.read_text()
                                              for m in RIG_MARKS)
        machine = rel.startswith(MACHINE_DIRS) or any(m in rel for m in MACHINE_MARKS)
        _GROUP[path] = "machine" if machine or (rig and os.environ.get(netns.ENV) != "1") \
            else rel
    return _GROUP[path]


def pytest_itemcollected(item: pytest.Item) -> None:
    # As each test is collected: xdist reads the groups into the test ids after collection.
    item.add_marker(pytest.mark.xdist_group(_group_of(Path(item.fspath))))


EARLY = ("tests/faults/test_soak.py", "tests/e2e/test_lathe_loop.py",
         "tests/e2e/test_store_backup.py", "tests/e2e/test_plant.py",
         "tests/integration/linuxcnc/test_linuxcnc_pull.py")
"""Files that mostly wait on what they started (a soak, a lathe turning parts, a service
backed up or reporting to the plant: 20-70 s each, a fifth of it CPU; LinuxCNC's lathe, 200 s
in one group, a tenth): in xdist's own order (the groups with most tests first) they came
late, and the suite's last half minute or minute ran on half the machine."""


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    # xdist's order (its --loadscope-reorder: the groups with most tests first), with EARLY's
    # groups before the rest; make test runs xdist with --no-loadscope-reorder to keep it.
    # Only xdist's workers collect for a schedule: a run on one process keeps its order.
    if os.environ.get("PYTEST_XDIST_WORKER") is None:
        return
    root = Path(__file__).resolve().parents[1]
    group = {id(i): _group_of(Path(i.fspath)) for i in items}
    size = Counter(group.values())
    early = {group[id(i)] for i in items
             if Path(i.fspath).relative_to(root).as_posix() in EARLY}
    first = {g: n for n, g in enumerate(dict.fromkeys(group.values()))}
    items.sort(key=lambda i: (group[id(i)] not in early, -size[group[id(i)]],
                              first[group[id(i)]]))


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
