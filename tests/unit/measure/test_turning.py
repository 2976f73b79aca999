"""Frames of a turning surface off the spindle axis, measured about its own centre
(``turning.measure_turning``), against the simulated rig's truth."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.sim.rig import RigConfig, ShaftRenderer, Turning
from service.measure.diameter import measure_frame
from service.measure.geometry import geometry_of
from service.measure.result import Method, Status
from service.measure.turning import measure_turning

DIAMETER_MM = 30.0


def frames(eccentricity_mm: float, n: int = 24, seed: int = 5
           ) -> tuple[list[np.ndarray], np.ndarray, ShaftRenderer]:
    rig = ShaftRenderer(RigConfig(turning=Turning(eccentricity_mm, 40.0)), seed=seed)
    angles = np.arange(n) * 360.0 / n + 7.0
    return [rig.render(DIAMETER_MM, i, spindle_deg=a) for i, a in enumerate(angles)], \
        angles, rig


@pytest.mark.parametrize("eccentricity_mm", [0.0, 0.04])
def test_a_surface_off_the_axis_is_measured_about_its_own_centre(eccentricity_mm: float
                                                                  ) -> None:
    images, angles, rig = frames(eccentricity_mm)
    geometry = geometry_of(rig.calibration)
    got = measure_turning(images, geometry, angles)
    r = got.runout
    assert r.ok and r.frames == len(images)
    # TIR within 2 um + 5 % of the truth (twice the eccentricity), with its uncertainty.
    assert abs(r.tir_mm - 2 * eccentricity_mm) <= 0.002 + 0.05 * 2 * eccentricity_mm
    assert r.tir_uncertainty_mm < 0.002
    ok = [m for m in got.measurements if m.status is Status.OK]
    assert len(ok) >= 0.9 * len(images)
    errors = np.array([m.diameter_mm - DIAMETER_MM for m in ok])
    sigmas = np.array([m.uncertainty_mm for m in ok])
    assert np.abs(errors).max() < 0.008
    assert (np.abs(errors) <= 4 * sigmas).all()
    assert abs(got.fused.diameter_mm - DIAMETER_MM) < 0.004
    if eccentricity_mm:
        # The axis method about the spindle axis refuses most of these frames and is
        # confidently wrong on the others.
        plain = [measure_frame(im, geometry, Method.AXIS) for im in images]
        wrong = [m for m in plain if m.status is Status.OK]
        assert len(wrong) < len(images) / 2
        assert min(abs(m.diameter_mm - DIAMETER_MM) for m in wrong) > 0.02


@pytest.mark.parametrize(("eccentricity_mm", "lobes"), [(0.04, ()), (0.0, ((3, 0.008, 20.0),))])
def test_the_form_comes_with_the_run_out(eccentricity_mm: float, lobes: tuple) -> None:
    """A round surface off the axis reads round (RONt within 1 um, no lobing); three lobes
    of 8 um read as three, odd, RONt 16 um within 1 um + 10 %."""
    rig = ShaftRenderer(RigConfig(turning=Turning(eccentricity_mm, 40.0, lobes)), seed=5)
    angles = np.arange(36) * 10.0 + 7.0
    images = [rig.render(DIAMETER_MM, i, spindle_deg=a) for i, a in enumerate(angles)]
    form = measure_turning(images, geometry_of(rig.calibration), angles, form=True).roundness
    assert form is not None and form.ok, form
    assert [h.order for h in form.harmonics][:2] == [2, 3]
    ront_true = 2 * sum(a for _, a, _ in lobes)
    assert abs(form.ront_mm - ront_true) <= 0.001 + 0.1 * ront_true
    assert form.ront_uncertainty_mm > 0
    assert form.dominant_order == (lobes[0][0] if lobes else 0)
    assert form.odd_lobing == bool(lobes)


def test_angles_must_match_the_frames() -> None:
    images, angles, rig = frames(0.0, n=4)
    with pytest.raises(ValueError, match="4 frames but 3 spindle angles"):
        measure_turning(images, geometry_of(rig.calibration), angles[:3])


def test_a_surface_out_of_round_and_off_the_axis_is_measured_without_its_form() -> None:
    """Three lobes of 8 um on a surface 30 um off: without the form taken off the points,
    the lobes move the free centres and most frames are refused as uncertain; with it,
    every diameter is measured and honest."""
    rig = ShaftRenderer(RigConfig(turning=Turning(0.03, 40.0, ((3, 0.008, 20.0),))), seed=5)
    angles = np.arange(36) * 10.0 + 7.0
    images = [rig.render(DIAMETER_MM, i, spindle_deg=a) for i, a in enumerate(angles)]
    got = measure_turning(images, geometry_of(rig.calibration), angles, form=True)
    assert abs(got.runout.tir_mm - 0.06) <= 0.002 + 0.05 * 0.06
    assert got.roundness is not None and got.roundness.dominant_order == 3
    ok = [m for m in got.measurements if m.status is Status.OK]
    assert len(ok) >= 0.9 * len(images)
    errors = np.array([m.diameter_mm - DIAMETER_MM for m in ok])
    assert np.abs(errors).max() < 0.010
    assert (np.abs(errors) <= 4 * np.array([m.uncertainty_mm for m in ok])).all()
    assert all("form taken off" in m.note for m in ok)


@pytest.mark.parametrize(("eccentricity_mm", "step_deg"), [(0.06, 13.0), (0.03, -29.0)])
def test_without_angles_the_turn_is_told_from_the_frames(eccentricity_mm: float,
                                                         step_deg: float) -> None:
    """Frames in order at a steady turn per frame (not given): the turn is estimated from
    the free centres, and the diameters and TIR are those of the frames with angles."""
    rig = ShaftRenderer(RigConfig(turning=Turning(eccentricity_mm, 130.0)), seed=8)
    angles = (np.arange(32) * step_deg + 50.0) % 360.0
    images = [rig.render(DIAMETER_MM, i, spindle_deg=a) for i, a in enumerate(angles)]
    got = measure_turning(images, geometry_of(rig.calibration), None)
    assert got.spindle is not None and got.spindle.ok, got.spindle
    assert abs(got.spindle.deg_per_frame - step_deg) < 0.3, got.spindle
    r = got.runout
    assert r.ok and abs(r.tir_mm - 2 * eccentricity_mm) <= 0.002 + 0.05 * 2 * eccentricity_mm
    ok = [m for m in got.measurements if m.status is Status.OK]
    assert len(ok) >= 0.9 * len(images)
    errors = np.array([m.diameter_mm - DIAMETER_MM for m in ok])
    assert np.abs(errors).max() < 0.010
    assert (np.abs(errors) <= 4 * np.array([m.uncertainty_mm for m in ok])).all()


def test_without_angles_a_surface_that_runs_true_is_checked_not_guessed() -> None:
    images, _, rig = frames(0.0, n=16)
    got = measure_turning(images, geometry_of(rig.calibration), None)
    assert got.spindle is not None and not got.spindle.ok
    assert not got.runout.ok and "do not go round" in got.runout.reason
    ok = [m for m in got.measurements if m.status is Status.OK]
    assert len(ok) >= 0.9 * len(images)  # concentric: the axis method's frames stand
    assert max(abs(m.diameter_mm - DIAMETER_MM) for m in ok) < 0.008
