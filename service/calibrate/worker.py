"""A calibration step in a worker process of its own, with a time budget.

A step's work grows with what it is given (a board's points, the images' size and number),
and OpenCV's detectors cannot be interrupted from a thread: a step past its budget, or whose
session is ended, is stopped by killing its process. The workers are forked from one
forkserver that has the calibration code loaded (a step starts in milliseconds, not the
seconds of importing OpenCV and SciPy), never from the service itself, whose threads (the
camera's, the event loop's) a fork would copy half-held.
"""

from __future__ import annotations

import multiprocessing
import multiprocessing.connection
import threading
import time
from collections.abc import Callable
from typing import Any, TypeVar

from service.calibrate.commands import StepError

_CONTEXT = multiprocessing.get_context("forkserver")
_CONTEXT.set_forkserver_preload(["service.calibrate.session"])
POLL_S = 0.1
"""How often the waiting thread looks at the budget and the stop."""
T = TypeVar("T")


class StepStoppedError(Exception):
    """The step was stopped because its session was ended; nothing of it is kept."""


def _work(conn: multiprocessing.connection.Connection, task: Callable[..., Any],
          args: tuple[Any, ...]) -> None:
    """In the worker: run the task and send back what came of it."""
    outcome: tuple[str, Any]
    try:
        outcome = ("result", task(*args))
    except StepError as err:
        outcome = ("refused", str(err))
    except Exception as err:  # a bug shows in the session, named
        outcome = ("error", f"{type(err).__name__}: {err}")
    conn.send(outcome)
    conn.close()


def run_in_worker(step: str, task: Callable[..., T], args: tuple[Any, ...], budget_s: float,
                  stop: threading.Event | None = None) -> T:
    """``task(*args)`` (a module's function: it is sent to the worker by name) for the
    calibration step ``step``, in a worker process; its result, or ``StepError`` when the
    task refused its inputs, failed, or ran past ``budget_s`` (the worker is killed), or
    ``StepStoppedError`` once ``stop`` is set (likewise)."""
    receive, send = _CONTEXT.Pipe(duplex=False)
    proc = _CONTEXT.Process(target=_work, args=(send, task, args), daemon=True,
                            name=f"calibration-{step}")
    proc.start()
    send.close()  # the worker holds the only sending end: its death ends the pipe
    deadline = time.monotonic() + budget_s
    try:
        while not receive.poll(POLL_S):
            if stop is not None and stop.is_set():
                raise StepStoppedError(f"{step}: stopped, its session was ended")
            if time.monotonic() > deadline:
                raise StepError(
                    f"{step}: stopped after its budget of {budget_s:g} s "
                    "(api.calibration_step_budget_s); a board of fewer points, fewer or "
                    "smaller images make it shorter")
        try:
            kind, value = receive.recv()
        except EOFError:
            proc.join(5)
            raise StepError(f"{step}: its worker ended without a result (exit code "
                            f"{proc.exitcode}; out of memory?)") from None
    finally:
        if proc.is_alive():
            proc.kill()
        proc.join(5)
        receive.close()
    if kind == "result":
        return value
    raise StepError(value if kind == "refused" else f"{step}: internal error: {value}")
