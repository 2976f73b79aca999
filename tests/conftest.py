"""Shared fixtures: a simulated rig and its exact calibration, a rendered calibration set."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from drivers.sim.rig import RigConfig, ShaftRenderer


@pytest.fixture(scope="session")
def renderer() -> ShaftRenderer:
    """The default simulated rig (geometry like the reference paper's)."""
    return ShaftRenderer(RigConfig(), seed=7)


@pytest.fixture(scope="session")
def calibration_images(tmp_path_factory) -> Path:
    """A simulated calibration session's images, as ``shaftgauge calibrate render`` writes
    them (``views/``, ``plane/``, ``axis/``): rendered once for every test that only reads
    them (half a minute of rendering each time otherwise)."""
    out = tmp_path_factory.mktemp("calibration-images")
    shaftgauge = str(Path(sys.executable).with_name("shaftgauge"))
    r = subprocess.run([shaftgauge, "calibrate", "render", "--output", str(out)],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    return out
