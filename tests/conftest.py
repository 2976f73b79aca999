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


LONG = ("tests/e2e/test_dashboard.py", "tests/faults/test_service_faults.py",
        "tests/integration/test_plane_laser_on.py", "tests/faults/test_cnc_trust.py",
        "tests/integration/test_recover_rig_targets.py", "tests/e2e/test_serve.py",
        "tests/integration/test_recover_rig.py", "tests/integration/test_calibration_session.py",
        "tests/integration/plant/test_opcua.py", "tests/integration/test_cli_calibrate.py",
        "tests/e2e/test_quality.py", "tests/integration/test_camera_contract.py",
        "tests/integration/test_cli_study.py", "tests/faults/test_runout.py",
        "tests/integration/test_gige_camera.py")
"""The files whose tests take longest on a worker (a minute or more of wall time in the
suite), longest first: after EARLY's, before the rest. In xdist's order (most tests first)
the long files of a test or two came last, and the phase ended on one or two of them."""


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    # EARLY's groups, then LONG's, then xdist's order (its --loadscope-reorder: the groups
    # with most tests first); make test runs xdist with --no-loadscope-reorder to keep it.
    # Only xdist's workers collect for a schedule: a run on one process keeps its order.
    if os.environ.get("PYTEST_XDIST_WORKER") is None:
        return
    root = Path(__file__).resolve().parents[1]
    group = {id(i): _group_of(Path(i.fspath)) for i in items}
    size = Counter(group.values())
    rank: dict[str, int] = {}
    for i in items:
        rel = Path(i.fspath).relative_to(root).as_posix()
        g = group[id(i)]
        if rel in EARLY or rel in LONG:
            rank[g] = min(rank.get(g, len(LONG)), -1 if rel in EARLY else LONG.index(rel))
    first = {g: n for n, g in enumerate(dict.fromkeys(group.values()))}
    items.sort(key=lambda i: (rank.get(group[id(i)], len(LONG)), -size[group[id(i)]],
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


@pytest.fixture(scope="session")
def detections(tmp_path_factory) -> Path:
    """Board detections kept for this run's workers (``service.calibrate.kept_detections``):
    the rendered session's images are read by half a dozen tests, in-process and through
    the command line, and detecting them is most of each (half a second an image)."""
    root = tmp_path_factory.getbasetemp()
    return (root.parent if os.environ.get("PYTEST_XDIST_WORKER") else root) / "detections"
