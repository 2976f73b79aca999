"""``shaftgauge study`` on rendered images of a master, as a user runs it."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pytest

from drivers.sim.frames import write_frames
from tests.integration.conftest import SHAFTGAUGE


@pytest.fixture(scope="module")
def master_images(tmp_path_factory) -> tuple[Path, list[str]]:
    out = tmp_path_factory.mktemp("master")
    paths = write_frames(out, [30.0], 75, seed=21)
    return out / "calibration.json", [str(p) for p in paths]


def study(cal: Path, images: list[str], *extra: str) -> subprocess.CompletedProcess:
    return subprocess.run([SHAFTGAUGE, "study", "--calibration", str(cal), *extra, *images],
                          capture_output=True, text=True, timeout=300)


def test_a_study_of_a_master_reports_cg_and_cgk(master_images) -> None:
    cal, images = master_images
    done = study(cal, images, "--master", "30.0", "--tolerance-mm", "0.2",
                 "--frames-per-value", "3")
    assert done.returncode == 0, done.stderr
    r = json.loads(done.stdout)
    assert r["n"] == 25 and len(r["values_mm"]) == 25 and r["refused"] == []
    assert r["cg"] > 1.33 and r["cgk"] > 1.33 and r["capable"] and abs(r["bias"]) < 0.003
    assert r["cgk"] <= r["cg"]


def test_a_master_off_its_certificate_fails_the_study(master_images) -> None:
    cal, images = master_images
    r = json.loads(study(cal, images[:25], "--master", "30.05", "--tolerance-mm", "0.2"
                         ).stdout)
    assert not r["capable"] and r["cgk"] < 0 and r["bias_significant"]


def test_bad_input_is_named(master_images) -> None:
    cal, images = master_images
    few = study(cal, images[:10], "--master", "30.0", "--tolerance-mm", "0.2")
    assert few.returncode == 2 and "at least 25" in few.stderr
    odd = study(cal, images[:25], "--master", "30.0", "--tolerance-mm", "0.2",
                "--frames-per-value", "3")
    assert odd.returncode == 2 and "whole values of 3 frames" in odd.stderr
    two = study(cal, images[:50], "--master", "30.0", "--tolerance-mm", "0.2",
                "--frames-per-value", "2")
    assert two.returncode == 2 and "3 and more" in two.stderr
