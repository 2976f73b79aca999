"""The spindle's turn per frame from free-fit centres of an eccentric surface (analytic arcs
of ``test_form``), and the cases where the frames cannot tell it."""

from __future__ import annotations

import numpy as np
import pytest

from service.measure.spindle_estimate import estimate_spindle_step
from tests.unit.measure.test_form import AXIS, frames, free_fits


def _estimate(e_um: float, step_deg: float, n: int = 40, phi: float = 70.0, seed: int = 5):
    index = np.arange(n)
    data = frames(e_um / 1000.0, phi, [], index * step_deg, seed=seed, n=200)
    centres, covs = free_fits(data)
    return estimate_spindle_step(centres, covs, AXIS, index)


@pytest.mark.parametrize("step", [11.0, -23.7, 97.3, 370.0 - 360.0 + 3.5, 151.0])
def test_the_turn_per_frame_is_recovered(step: float) -> None:
    est = _estimate(40.0, step)
    assert est.ok, est.reason
    folded = (step + 180.0) % 360.0 - 180.0
    assert abs(est.deg_per_frame - folded) <= max(4.0 * est.uncertainty_deg, 0.05), est
    assert est.uncertainty_deg < 0.2
    assert est.direction_chi2 > 25.0


def test_an_alias_of_the_frame_rate_is_the_same_angles() -> None:
    """A spindle one and a bit turns a frame is the same angles as a bit."""
    a, b = _estimate(40.0, 370.0), _estimate(40.0, 10.0)
    assert a.ok and b.ok
    assert a.deg_per_frame == pytest.approx(b.deg_per_frame, abs=1e-6)
    assert np.allclose(a.angles(np.arange(5)), [0.0, 10.0, 20.0, 30.0, 40.0], atol=0.5)


def test_a_surface_that_runs_true_gives_no_turn() -> None:
    est = _estimate(0.0, 11.0)
    assert not est.ok and "do not go round" in est.reason


@pytest.mark.parametrize("step", [0.0, 180.0, 120.0])
def test_a_frame_rate_locked_to_the_spindle_gives_no_turn(step: float) -> None:
    est = _estimate(40.0, step)
    assert not est.ok, est
    assert "locked" in est.reason or "cannot" in est.reason or "two turns" in est.reason


def test_too_few_frames_are_named() -> None:
    est = _estimate(40.0, 11.0, n=5)
    assert not est.ok and "need 8" in est.reason
