"""The test suite's own plumbing: each ``pytest -n`` worker's loopback (``tests/netns.py``)
and the groups that keep what must not overlap on one worker (``tests/conftest.py``)."""

from __future__ import annotations

import os
import socket
from pathlib import Path

import pytest

from tests import conftest, netns

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.skipif(not netns.can_unshare(), reason="no privilege to make network namespaces")
def test_a_loopback_of_its_own_takes_the_port_the_host_holds() -> None:
    with socket.socket() as host:  # the host's 127.0.0.1 holds a port ...
        host.bind(("127.0.0.1", 0))
        host.listen()
        port = host.getsockname()[1]
        pid = os.fork()
        if pid == 0:  # ... which a new namespace's 127.0.0.1 has free, and can connect within
            code = 1
            try:
                before = os.readlink("/proc/thread-self/ns/net")
                netns.enter_own_loopback()
                with socket.socket() as own, socket.socket() as peer:
                    own.bind(("127.0.0.1", port))
                    own.listen()
                    peer.connect(("127.0.0.1", port))
                    code = 0 if os.readlink("/proc/thread-self/ns/net") != before else 2
            finally:
                os._exit(code)
        _, status = os.waitpid(pid, 0)
    assert os.waitstatus_to_exitcode(status) == 0


def test_linuxcnc_and_the_speed_guard_always_share_one_worker(monkeypatch) -> None:
    for own in ("1", "0"):
        monkeypatch.setenv(netns.ENV, own)
        conftest._GROUP.clear()
        assert conftest._group_of(
            ROOT / "tests/integration/linuxcnc/test_linuxcnc_pull.py") == "machine"
        assert conftest._group_of(ROOT / "tests/integration/test_speed_guard.py") == "machine"
        camera = conftest._group_of(ROOT / "tests/integration/test_gige_camera.py")
        assert camera == ("tests/integration/test_gige_camera.py" if own == "1" else "machine")
        assert conftest._group_of(ROOT / "tests/unit/test_architecture.py") == \
            "tests/unit/test_architecture.py"
    conftest._GROUP.clear()


def test_free_ports_given_out_one_after_another_differ() -> None:
    """A service's ports are taken one after another before it binds any: each must differ
    (two calls in a row once gave its REST and Modbus servers the same port)."""
    from tests.integration.conftest import free_port

    ports = [free_port() for _ in range(200)]
    assert len(set(ports)) == len(ports)
