"""`shaftgauge calibrate ...` from a rendered session to a mastered calibration."""

from __future__ import annotations

import json
import subprocess

import numpy as np
import pytest

from calib_store.model import load_calibration
from tests.integration.conftest import SHAFTGAUGE


def run(*args, cwd=None) -> subprocess.CompletedProcess:
    return subprocess.run([SHAFTGAUGE, *map(str, args)], capture_output=True, text=True,
                          timeout=300, cwd=cwd)


@pytest.fixture
def session(calibration_images):
    """``shaftgauge calibrate render``'s session (rendered once a run, read only)."""
    return calibration_images


def test_the_whole_chain(session, tmp_path, detections) -> None:
    s, w = session, tmp_path
    views = sorted(str(p) for p in (s / "views").glob("*.png"))
    assert run("calibrate", "intrinsics", "--output", w / "i.json", "--detections", detections,
               *views).returncode == 0
    pairs = [str(s / "plane" / f"pose{i}_{k}.png") for i in range(4) for k in ("off", "on")]
    assert run("calibrate", "plane", "--intrinsics", w / "i.json", "--output", w / "p.json",
               "--detections", detections, *pairs).returncode == 0
    axis = sorted(str(p) for p in (s / "axis").glob("*.png"))
    assert run("calibrate", "axis", "--intrinsics", w / "i.json", "--plane", w / "p.json",
               "--output", w / "a.json", "--detections", detections, *axis).returncode == 0
    r = run("calibrate", "build", "--intrinsics", w / "i.json", "--plane", w / "p.json",
            "--axis", w / "a.json", "--output", w / "cal.json", "--report", w / "rep.json")
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["verdict"] in ("good", "marginal")
    report = json.loads((w / "rep.json").read_text())["figures"]
    assert report["target"] == {"board": "chess:11x8x8", "detector": "sb"}
    assert report["images"]["intrinsics"]["conversion"] == "grey as read"
    assert set(report["light_plane"]["how"].values()) == {
        "the difference of the laser-off and laser-on images"}
    cal, truth = load_calibration(w / "cal.json"), load_calibration(s / "truth.json")
    assert np.allclose(cal.camera_matrix[0][0], truth.camera_matrix[0][0], rtol=0.002)
    r = run("calibrate", "master", "--calibration", w / "cal.json",
            "--master", 30, *sorted((s / "master30").glob("*.png")),
            "--master", 40, *sorted((s / "master40").glob("*.png")),
            "--output", w / "master.json")
    assert r.returncode == 0, r.stderr
    m = json.loads(r.stdout)
    assert abs(m["scale"] - 1) < 0.001 and abs(m["offset_mm"]) < 0.05
    for master in m["masters"]:  # the recovered calibration measures within 15 um
        assert abs(master["measured_mm"] - master["certified_mm"]) < 0.015
    # The offline chain is the service's: calibrate, master, measure with the correction.
    for certified in (30, 40):
        images = sorted((s / f"master{certified}").glob("*.png"))
        plain, fixed = (json.loads(run("measure", "--calibration", w / "cal.json", "--fuse",
                                       *extra, *images).stdout)
                        for extra in ((), ("--correction", w / "master.json")))
        assert fixed["diameter_mm"] == pytest.approx(
            m["scale"] * plain["diameter_mm"] + m["offset_mm"], abs=2e-6)
        assert abs(fixed["diameter_mm"] - certified) < 0.001


def test_bad_steps_exit_2_saying_what_to_do(session, tmp_path) -> None:
    s = session
    few = run("calibrate", "intrinsics", "--output", tmp_path / "i.json",
              *sorted((s / "views").glob("*.png"))[:3])
    assert few.returncode == 2 and "need 6" in few.stderr
    odd = run("calibrate", "plane", "--intrinsics", tmp_path / "i.json", "--output",
              tmp_path / "p.json", s / "plane" / "pose0_off.png")
    assert odd.returncode == 2 and ("two by two" in odd.stderr or "failed" in odd.stderr)
    board = run("calibrate", "intrinsics", "--board", "banana", "--output", tmp_path / "x.json",
                s / "views" / "view_00.png")
    assert board.returncode == 2 and "COLSxROWSxMM" in board.stderr
