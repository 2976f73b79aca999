"""A loopback of its own for each ``pytest -n`` worker (Linux network namespaces).

The simulated GigE camera has one port (GVCP 3956 on 127.0.0.1), so tests that stream from it
could only run one after another. A worker in a network namespace of its own has its own
``lo``: its camera, its services and their ports cannot meet another worker's, and the rig's
tests spread over the workers. Creating one needs ``CAP_SYS_ADMIN`` (root, as CI and
``make test`` on a fresh machine run); without it the rig's tests share one worker as before.
Only the network is separate: shared memory, files and LinuxCNC's realtime stay common.
"""

from __future__ import annotations

import ctypes
import fcntl
import os
import socket
import struct

CLONE_NEWNET = 0x40000000
_SIOCGIFFLAGS, _SIOCSIFFLAGS, _IFF_UP = 0x8913, 0x8914, 0x1
ENV = "SHAFTGAUGE_TEST_NETNS"
"""Set by the controller (``1``: the workers can and do each unshare their network)."""


def enter_own_loopback() -> None:
    """Move the calling thread (and what it starts later: threads, subprocesses) into a new
    network namespace and bring its loopback up (which gives it 127.0.0.1 and ::1).

    Raises ``OSError`` when the kernel refuses (no privilege)."""
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.unshare(CLONE_NEWNET) != 0:
        err = ctypes.get_errno()
        raise OSError(err, f"unshare(CLONE_NEWNET): {os.strerror(err)}")
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        request = struct.pack("16sh", b"lo", 0)
        flags = struct.unpack("16sh", fcntl.ioctl(s, _SIOCGIFFLAGS, request)[:18])[1]
        fcntl.ioctl(s, _SIOCSIFFLAGS, struct.pack("16sh", b"lo", flags | _IFF_UP))


def can_unshare() -> bool:
    """Whether a worker could enter a loopback of its own (tried in a child process, so that
    this one keeps the host's network)."""
    pid = os.fork()
    if pid == 0:  # the child: try, and report by exit status only
        try:
            enter_own_loopback()
            code = 0
        except OSError:
            code = 1
        os._exit(code)
    _, status = os.waitpid(pid, 0)
    return os.waitstatus_to_exitcode(status) == 0
