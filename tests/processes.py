"""Ending a test's process group without signalling someone else's.

The kernel gives a pid out again once its process is reaped, and this machine's ``pid_max``
is 32768 while a run of the suite starts thousands of processes: a group id signalled after
its leader was reaped can be a new leader's, Chromium's or another worker's service. So a
group is signalled only while its leader is unreaped (a zombie keeps its pid), and reaped
after.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import time


def exited(proc: subprocess.Popen, timeout_s: float) -> bool:
    """Whether ``proc`` ended within ``timeout_s``, leaving it unreaped (``WNOWAIT``)."""
    deadline = time.monotonic() + timeout_s
    while proc.returncode is None:
        with contextlib.suppress(ChildProcessError):
            if os.waitid(os.P_PID, proc.pid, os.WEXITED | os.WNOWAIT | os.WNOHANG):
                return True
        if time.monotonic() > deadline:
            return False
        time.sleep(0.05)
    return True


def end_group(proc: subprocess.Popen, term_wait_s: float = 0.0) -> int:
    """End ``proc``'s process group: SIGTERM to ``proc`` alone and up to ``term_wait_s`` for
    it to end by itself (``0``: not asked), then SIGKILL to what is left of its group, then
    reap it. Its exit status."""
    if proc.returncode is None:
        if term_wait_s > 0 and not exited(proc, 0.0):
            with contextlib.suppress(ProcessLookupError):
                os.kill(proc.pid, signal.SIGTERM)
            exited(proc, term_wait_s)
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)  # unreaped: the group id is still its own
    return proc.wait(10)
