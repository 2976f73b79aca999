"""The service's run-out tracker (service/measure/runout_track.py) against analytic truth: the
free fits of an eccentric circle's arcs at the angles an encoder-triggered camera sees, fed
one frame at a time as the publisher does."""

from __future__ import annotations

import math

import numpy as np
import pytest

from service.measure.runout_track import RunoutTracker, SpindleAngles
from tests.unit.measure.test_form import AXIS, frames, free_fits


def feed(tracker: RunoutTracker, e_um: float, phi: float, step_deg: float, n: int,
         first_id: int = 0, seed: int = 5) -> list[float]:
    angles = SpindleAngles(step_deg)
    ids = np.arange(first_id, first_id + n)
    deg = np.array([angles.at(int(i)) for i in ids])
    centres, covs = free_fits(frames(e_um / 1000.0, phi, [], deg, seed=seed))
    return [tracker.update(int(i), float(d), c, v, AXIS)
            for i, d, c, v in zip(ids, deg, centres, covs, strict=True)]


def test_spindle_angles_count_from_the_frame_number() -> None:
    a = SpindleAngles(37.0, zero_deg=350.0)
    assert a.at(0) == pytest.approx(350.0)
    assert a.at(1) == pytest.approx(27.0)
    assert 0.0 <= a.at(10**9) < 360.0


@pytest.mark.parametrize(("e_um", "phi"), [(0.0, 0.0), (25.0, 70.0), (100.0, 200.0)])
def test_the_surface_centre_at_each_angle_once_a_revolution_is_seen(e_um: float,
                                                                   phi: float) -> None:
    t = RunoutTracker()
    assert t.prior_at(0, 0.0, AXIS, 0.001) is None
    feed(t, e_um, phi, 37.0, 30)
    assert t.runout is not None, t.reason
    assert t.runout.eccentricity_mm == pytest.approx(e_um / 1000.0, abs=max(
        3.0 * t.runout.eccentricity_uncertainty_mm, 0.0008))
    for theta in (0.0, 123.0, 271.0):
        centre, sigma = t.prior_at(40, theta, AXIS, 0.001)
        th, ph = math.radians(theta), math.radians(phi)
        truth = AXIS + e_um / 1000.0 * np.array([math.cos(ph + th), math.sin(ph + th)])
        assert np.linalg.norm(centre - truth) <= 3.0 * sigma
        assert sigma >= 0.001  # never better than the axis it is reckoned from
    status = t.status()
    assert status["known"] and status["tir_mm"] == pytest.approx(t.runout.tir_mm)
    assert t.runout.tir_mm <= 2 * t.runout.eccentricity_mm  # less the noise's share


def test_a_frame_rate_locked_to_the_spindle_never_knows_it() -> None:
    t = RunoutTracker()
    feed(t, 50.0, 30.0, 360.0, 60)  # every frame at the same angle
    assert t.runout is None
    assert "locked" in t.reason and "cover 0 degrees" in t.reason
    assert t.prior_at(60, 0.0, AXIS, 0.001) is None


def test_the_first_frames_are_not_enough() -> None:
    t = RunoutTracker(min_frames=12)
    feed(t, 50.0, 30.0, 37.0, 11)
    assert t.runout is None and "11 free fits" in t.reason


def test_another_clamping_is_noticed_and_learnt_again() -> None:
    t = RunoutTracker()
    feed(t, 50.0, 30.0, 37.0, 30)
    before = t.runout
    assert before is not None
    # Reclamped 80 um off the other way: the centres leave the run-out known.
    sig = feed(t, 80.0, 210.0, 37.0, 3, first_id=30, seed=6)
    assert min(sig) > t.gate
    assert t.runout is None and "new part or clamping" in t.reason and t.resets == 1
    feed(t, 80.0, 210.0, 37.0, 30, first_id=33, seed=7)
    assert t.runout is not None
    assert t.runout.eccentricity_mm == pytest.approx(0.080, abs=0.002)


def test_one_stray_frame_does_not_forget_it() -> None:
    t = RunoutTracker()
    feed(t, 50.0, 30.0, 37.0, 30)
    far = np.array([AXIS[0] + 0.5, AXIS[1]])
    assert t.update(30, SpindleAngles(37.0).at(30), far, np.eye(2) * 1e-6, AXIS) > t.gate
    assert t.runout is not None and t.resets == 0


def test_frame_numbers_going_back_lose_the_phase() -> None:
    t = RunoutTracker()
    feed(t, 50.0, 30.0, 37.0, 30, first_id=65500)
    assert t.runout is not None
    assert t.prior_at(3, 0.0, AXIS, 0.001) is None  # the camera started again
    feed(t, 50.0, 30.0, 37.0, 1, first_id=1)
    assert t.runout is None and t.resets == 1


def test_a_window_begun_on_the_last_part_learns_the_new_one() -> None:
    """The part changed while the run-out was being learnt: the last part's frames in the
    window lie off the new run-out and are left out, not averaged in."""
    t = RunoutTracker()
    feed(t, 0.0, 0.0, 37.0, 8)            # the concentric part, not known yet (8 < 12)
    assert t.runout is None
    feed(t, 50.0, 30.0, 37.0, 40, first_id=8, seed=8)
    assert t.runout is not None, t.reason
    assert t.runout.tir_mm == pytest.approx(0.100, abs=0.002)


def test_the_form_of_the_frames_measured_about_the_surface_centre() -> None:
    """Three lobes of 8 um on an eccentric surface, from frames thinned to 100 points."""
    from service.measure.result import Measurement, Method, Status
    from service.measure.runout_track import FormFrames

    form = FormFrames()
    assert not form.roundness().ok
    deg = np.array([SpindleAngles(37.0).at(i) for i in range(36)])
    for theta, (pts, centre) in zip(deg, frames(0.05, 30.0, [(3, 0.008, 40.0)], deg),
                                    strict=True):
        form.add(Measurement(Status.OK, Method.AXIS, 30.0, center_mm=tuple(centre),
                             section_mm=pts, spindle_deg=float(theta), about_runout=True))
    form.add(Measurement(Status.OK, Method.AXIS, 30.0, center_mm=(0.0, 0.0),
                         section_mm=pts, spindle_deg=0.0))  # about the axis: not taken
    assert form.added == 36
    shape = form.roundness()
    assert shape.ok, shape.reason
    assert shape.dominant_order == 3 and shape.odd_lobing
    assert shape.ront_mm == pytest.approx(0.016, abs=0.001 + 0.1 * 0.016)
    form.clear()
    assert not form.roundness().ok


def test_the_position_settles_after_free_fits_that_pass_and_unsettles_on_a_doubt() -> None:
    from service.measure.runout_track import Settling

    s = Settling(frames=3, max_gap_s=0.5)
    for i in range(2):
        s.seen(i * 0.01, True, True)
    assert not s.settled
    s.seen(0.02, True, None)   # no free fit: neither way
    s.seen(0.03, True, True)
    assert s.settled
    s.seen(0.04, True, False)  # a free fit refused as off the axis
    assert not s.settled
    for i in range(3):
        s.seen(0.05 + i * 0.01, True, True)
    assert s.settled
    s.seen(0.08, False, None)  # no shaft under the laser: it may have been taken out
    assert not s.settled
    for i in range(3):
        s.seen(0.09 + i * 0.01, True, True)
    s.seen(2.0, True, None)    # the spindle stood (no encoder pulses)
    assert not s.settled


def test_the_frames_check_the_tracked_axis() -> None:
    """The surface's frames go round an axis 4 um off the one tracked: the check says so."""
    t = RunoutTracker()
    angles = SpindleAngles(37.0)
    deg = np.array([angles.at(i) for i in range(40)])
    centres, covs = free_fits(frames(0.05, 30.0, [], deg))
    tracked = AXIS - np.array([0.004, 0.0])
    for i, (d, c, v) in enumerate(zip(deg, centres, covs, strict=True)):
        t.update(i, float(d), c, v, tracked)
    check = t.status()["axis_check"]
    assert check is not None
    if t.runout is None:  # a fixed offset the eccentricity alone cannot take: named
        assert "um off the tracked spindle axis" in t.reason, t.reason
    shift = np.array(check["shift_mm"])
    assert np.linalg.norm(shift - [0.004, 0.0]) <= max(4 * check["shift_uncertainty_mm"], 0.001)


def test_the_publisher_takes_the_known_form_off_a_frame() -> None:
    """A lobed surface's frame measured about its centre: with the form known, its circle is
    that of the form's reference circle (here R = 15 mm exactly), not the arc's share of it."""
    import math

    from calib_store.store import CalibrationInfo
    from service.measure import fit as fits
    from service.measure.axis_track import AxisTracker
    from service.measure.form import ConcentricityWatch
    from service.measure.result import Measurement, Method, Status
    from service.runtime.calibration import CalibrationInUse
    from service.runtime.publish import positioned

    lobes = [(2, 0.008, 20.0)]
    runout = RunoutTracker()
    feed(runout, 50.0, 30.0, 37.0, 30)
    runout.form.lobes = [(2, 0.008, math.radians(20.0))]
    in_use = CalibrationInUse(CalibrationInfo(1, 0.0, "", "", True, None), None, None, None,
                              AxisTracker(AXIS, 0.001), ConcentricityWatch(), runout)
    plain_err, got_err = [], []
    for i in range(31, 31 + 36):
        theta = SpindleAngles(37.0).at(i)
        (pts, centre), = frames(0.05, 30.0, lobes, np.array([theta]), noise_mm=0.0002, seed=i)
        plain = fits.fit_axis_prior(pts, centre, 0.0015)
        m = Measurement(Status.OK, Method.AXIS, plain.diameter, center_mm=tuple(plain.center),
                        uncertainty_mm=0.002, section_mm=pts, spindle_deg=theta,
                        about_runout=True)
        got, _ = positioned(m, i, in_use)
        assert got.status is Status.OK and "form taken off" in got.note
        plain_err.append(abs(plain.diameter - 30.0))
        got_err.append(abs(got.diameter_mm - 30.0))
    assert np.mean(got_err) < 0.5 * np.mean(plain_err), (np.mean(got_err), np.mean(plain_err))


def test_a_frame_seen_again_counts_once_in_the_form() -> None:
    """A camera replaying its frames shows the form the same points again at the same
    angles: counted each time, their noise would shrink the harmonics' uncertainty and read
    as lobes. Each replaces itself."""
    from service.measure.result import Measurement, Method, Status
    from service.measure.runout_track import FormFrames

    deg = np.array([SpindleAngles(37.0).at(i) for i in range(20)])
    ring = [Measurement(Status.OK, Method.AXIS, 30.0, center_mm=tuple(centre),
                        section_mm=pts, spindle_deg=float(theta), about_runout=True)
            for theta, (pts, centre) in zip(deg, frames(0.05, 30.0, [], deg), strict=True)]
    once, replayed = FormFrames(), FormFrames()
    for m in ring:
        once.add(m)
    for k in range(200):
        replayed.add(ring[k % len(ring)])
    assert once.added == 20 and replayed.added == 200
    a, b = once.roundness(), replayed.roundness()
    assert a.ok and b.ok
    assert [h.amplitude_uncertainty_mm for h in a.harmonics] == \
        [h.amplitude_uncertainty_mm for h in b.harmonics]
