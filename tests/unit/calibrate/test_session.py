"""The calibration session outside HTTP: kept on disk, found again after a restart, capped,
and one step dispatch for the API and the CLI."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from service.calibrate.commands import StepError
from service.calibrate.session import CalibrationSessions, SessionLimitError
from service.calibrate.worker import StepStoppedError
from tests.waiting import DEADLINE_S, until


def test_an_open_session_survives_a_restart(tmp_path) -> None:
    sessions = CalibrationSessions(tmp_path, max_open=2, max_images=5, expiry_h=24)
    s = sessions.create("11x8x8", "monday", "technician")
    s.add_image("view", np.zeros((8, 8), np.uint8), sessions.max_images)
    r = s.run("intrinsics")  # one image without a board: refused, and the refusal recorded
    assert not r.ok and "need 6" in r.reason
    again = CalibrationSessions(tmp_path, max_open=2, max_images=5, expiry_h=24)
    t = again.get(s.id)
    assert t.images["view"] == s.images["view"] and t.note == "monday"
    assert t.progress["state"] == "failed" and "need 6" in t.progress["message"]


def test_a_step_running_at_a_restart_is_marked_interrupted(tmp_path) -> None:
    sessions = CalibrationSessions(tmp_path, max_open=2, max_images=5, expiry_h=24)
    s = sessions.create("11x8x8", "", "technician")
    s.progress = {"step": "axis", "state": "running", "message": "axis: working"}
    s.save()
    t = CalibrationSessions(tmp_path, 2, 5, 24).get(s.id)
    assert t.progress["state"] == "failed" and "interrupted" in t.progress["message"]


def test_caps_and_a_damaged_session_file(tmp_path) -> None:
    sessions = CalibrationSessions(tmp_path, max_open=1, max_images=1, expiry_h=24)
    s = sessions.create("9x6x6", "", "technician")
    with pytest.raises(SessionLimitError, match="max_calibration_sessions"):
        sessions.create("9x6x6", "", "technician")
    s.add_image("axis", np.zeros((4, 4), np.uint8), sessions.max_images)
    with pytest.raises(SessionLimitError, match="max_session_images"):
        s.add_image("axis", np.zeros((4, 4), np.uint8), sessions.max_images)
    with pytest.raises(StepError, match="COLSxROWSxMM"):
        sessions.create("banana", "", "technician")
    (s.dir / "session.json").write_text("{not json")
    assert CalibrationSessions(tmp_path, 1, 1, 24)._open == {}  # not served, left on disk
    assert (s.dir / "session.json").exists()


def test_ended_activated_and_failed_sessions_free_their_places(tmp_path) -> None:
    sessions = CalibrationSessions(tmp_path, max_open=2, max_images=5, expiry_h=24)
    a = sessions.create("9x6x6", "", "technician")
    b = sessions.create("9x6x6", "", "technician")
    with pytest.raises(SessionLimitError, match=f"{a.id}.*DELETE"):
        sessions.create("9x6x6", "", "technician")
    sessions.end(a.id)  # ended: its folder goes with it
    assert not a.dir.exists()
    with pytest.raises(KeyError):
        sessions.get(a.id)
    c = sessions.create("9x6x6", "", "technician")
    b.activated_id = 7  # its result is in use
    c.add_image("view", np.zeros((8, 8), np.uint8), sessions.max_images)
    assert not c.run("intrinsics").ok  # its last step failed
    assert not b.counts and not c.counts
    d = sessions.create("9x6x6", "", "technician")
    e = sessions.create("9x6x6", "", "technician")
    # Finished sessions are kept for review, at most max_open of them, the oldest going first.
    assert {s.id for s in sessions.listing()} <= {b.id, c.id, d.id, e.id}
    assert len(sessions.listing()) <= 2 * sessions.max_open


def test_a_read_does_not_renew_a_session(tmp_path) -> None:
    sessions = CalibrationSessions(tmp_path, max_open=2, max_images=5, expiry_h=1)
    s = sessions.create("9x6x6", "", "technician")
    s.touched -= 3000.0  # 50 minutes since its last change
    before = s.touched
    assert sessions.get(s.id).touched == before
    s.touched -= 700.0  # past the hour: reads kept it from nothing
    with pytest.raises(KeyError):
        sessions.get(s.id)


def slow_session(sessions: CalibrationSessions):
    """A session whose intrinsics step takes many seconds: a board of 60x60 corners (the
    most a side) searched for in images of noise."""
    s = sessions.create("60x60x4", "", "technician")
    noise = np.random.default_rng(0).integers(0, 256, (1024, 1280), dtype=np.uint8)
    for _ in range(3):
        s.add_image("view", noise, sessions.max_images)
    return s


def test_a_step_past_its_budget_is_stopped_and_fails_naming_the_setting(tmp_path) -> None:
    sessions = CalibrationSessions(tmp_path, 2, 5, 24, step_budget_s=0.5)
    s = slow_session(sessions)
    with pytest.raises(StepError, match="calibration_step_budget_s"):
        sessions.run(s, "intrinsics")
    assert s.progress["state"] == "failed" and "budget of 0.5 s" in s.progress["message"]
    assert not s.counts  # a failed step frees its place
    assert sessions.run(sessions.create("9x6x6", "", "technician"), "intrinsics").ok is False


def test_a_session_is_ended_while_its_step_runs(tmp_path) -> None:
    sessions = CalibrationSessions(tmp_path, 2, 5, 24, step_budget_s=3600.0)
    s = slow_session(sessions)
    outcome: list[BaseException] = []

    def run() -> None:
        try:
            sessions.run(s, "intrinsics")
        except BaseException as err:
            outcome.append(err)

    thread = threading.Thread(target=run)
    thread.start()
    until(lambda: s.id in sessions._stops and s.progress["state"] == "running",
          "the step running")
    sessions.end(s.id)
    with pytest.raises(KeyError):
        sessions.get(s.id)
    thread.join(DEADLINE_S)
    assert not thread.is_alive() and isinstance(outcome[0], StepStoppedError), outcome
    assert not s.dir.exists()
    assert len(sessions.listing()) == 0
