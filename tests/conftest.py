"""Shared fixtures: a simulated rig and its exact calibration."""

from __future__ import annotations

import pytest

from drivers.sim.rig import RigConfig, ShaftRenderer


@pytest.fixture(scope="session")
def renderer() -> ShaftRenderer:
    """The default simulated rig (geometry like the reference paper's)."""
    return ShaftRenderer(RigConfig(), seed=7)
