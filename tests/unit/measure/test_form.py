"""Run-out and roundness (service/measure/form.py) against analytic truth: an eccentric, lobed
circle sampled on the short arc a line laser sees, at known spindle angles, with seeded
noise; each frame fitted freely as the measurement does."""

from __future__ import annotations

import math

import numpy as np
import pytest

from service.measure import fit as fits
from service.measure.form import fit_runout, rotation, roundness

AXIS = np.array([0.4, -0.3])
R = 15.0


def frames(e_mm: float, phi_deg: float, lobes: list[tuple[int, float, float]],
           angles_deg: np.ndarray, noise_mm: float = 0.0015, seed: int = 5,
           arc_deg: tuple[float, float] = (200.0, 310.0), n: int = 400):
    """Each frame's points on the section and its surface's true centre."""
    rng = np.random.default_rng(seed)
    out = []
    for theta in angles_deg:
        th = math.radians(theta)
        centre = AXIS + rotation(th) @ (e_mm * np.array([math.cos(math.radians(phi_deg)),
                                                          math.sin(math.radians(phi_deg))]))
        alpha = np.radians(np.linspace(*arc_deg, n))
        r = R + sum(a * np.cos(k * (alpha - th) - math.radians(p)) for k, a, p in lobes)
        r = r + rng.normal(0.0, noise_mm, n)
        pts = centre + r[:, None] * np.column_stack([np.cos(alpha), np.sin(alpha)])
        out.append((pts, centre))
    return out


def free_fits(data):
    centres, covs = [], []
    for pts, _ in data:
        f = fits.fit_geometric(pts)
        cov = fits.circle_covariance(pts, f.center, f.radius, inliers=f.inliers)
        centres.append(f.center)
        covs.append(cov[:2, :2])
    return np.array(centres), np.array(covs)


@pytest.mark.parametrize(("e_um", "phi"), [(0.0, 0.0), (10.0, 40.0), (60.0, 250.0),
                                           (100.0, 130.0)])
def test_runout_recovers_eccentricity_and_phase(e_um: float, phi: float) -> None:
    angles = np.arange(0.0, 720.0, 15.0)  # two revolutions
    data = frames(e_um / 1000.0, phi, [], angles)
    centres, covs = free_fits(data)
    ro = fit_runout(centres, covs, angles, AXIS)
    assert ro.ok, ro.reason
    assert ro.eccentricity_mm == pytest.approx(e_um / 1000.0, abs=max(
        3.0 * ro.eccentricity_uncertainty_mm, 0.0005))
    assert ro.tir_mm == pytest.approx(2.0 * math.sqrt(max(
        ro.eccentricity_mm ** 2 - np.trace(ro.parameter_cov[:2, :2]), 0.0)))
    assert ro.tir_mm == pytest.approx(2.0 * e_um / 1000.0, abs=max(
        6.0 * ro.eccentricity_uncertainty_mm, 0.001))
    if e_um >= 10.0:
        gap = (ro.eccentricity_deg - phi + 180.0) % 360.0 - 180.0
        assert abs(gap) <= max(3.0 * ro.eccentricity_deg_uncertainty, 1.0)
    assert np.hypot(*ro.axis_shift_mm) < 0.001  # the calibrated axis stands
    assert 0.2 < ro.chi2_per_dof < 5.0


def test_noise_alone_does_not_read_as_run_out() -> None:
    """On a concentric surface the fitted eccentricity is noise, and its length is always
    positive: 2 |e| would read as run-out. The TIR takes the noise's share out: over many
    draws its mean stays near zero, where 2 |e| does not."""
    angles = np.arange(0.0, 360.0, 7.5)
    naive, tirs, sigmas = [], [], []
    for seed in range(30):
        data = frames(0.0, 0.0, [], angles, noise_mm=0.004, seed=100 + seed, n=150)
        centres, covs = free_fits(data)
        ro = fit_runout(centres, covs, angles, AXIS)
        naive.append(2.0 * ro.eccentricity_mm)
        tirs.append(ro.tir_mm)
        sigmas.append(ro.eccentricity_uncertainty_mm)
    sigma = float(np.mean(sigmas))
    assert np.mean(naive) > 2.0 * sigma  # 2 |e| of pure noise: about 2.5 sigma
    assert np.mean(tirs) < 0.5 * np.mean(naive), (np.mean(tirs), np.mean(naive))


def test_runout_finds_a_calibrated_axis_that_is_off() -> None:
    """A surface just turned is concentric: its centres over a revolution are the spindle
    axis itself, 57 um off the calibrated one here."""
    angles = np.arange(0.0, 360.0, 10.0)
    data = frames(0.0, 0.0, [], angles)
    centres, covs = free_fits(data)
    wrong = AXIS + np.array([0.040, -0.0405])
    ro = fit_runout(centres, covs, angles, wrong)
    assert ro.ok
    assert np.allclose(ro.axis_shift_mm, AXIS - wrong, atol=0.002)
    assert ro.eccentricity_mm < 0.002


def test_runout_says_why_not() -> None:
    centres, covs = free_fits(frames(0.05, 0.0, [], np.array([0.0, 10.0, 20.0])))
    ro = fit_runout(centres, covs, np.array([0.0, 10.0, 20.0]), AXIS)
    assert not ro.ok and "cover 20 degrees" in ro.reason
    assert not fit_runout(centres[:1], covs[:1], np.array([0.0]), AXIS).ok


@pytest.mark.parametrize("lobes", [[(3, 0.008, 30.0)], [(2, 0.004, 0.0), (5, 0.003, 200.0)],
                                   [(7, 0.002, 90.0)]])
def test_roundness_recovers_the_lobes(lobes) -> None:
    angles = np.arange(0.0, 1080.0, 7.5)  # three revolutions, the arcs overlap
    e, phi = 0.03, 75.0
    data = frames(e, phi, lobes, angles)
    centres, covs = free_fits(data)
    ro = fit_runout(centres, covs, angles, AXIS)
    assert ro.ok
    assert ro.eccentricity_mm == pytest.approx(e, abs=0.002 + 0.05 * e)
    beta, radius = [], []
    for (pts, _), theta in zip(data, angles, strict=True):
        rel = pts - ro.center_at(AXIS, theta)
        beta.append(np.degrees(np.arctan2(rel[:, 1], rel[:, 0])) - theta)
        radius.append(np.hypot(*rel.T))
    form = roundness(np.concatenate(beta), np.concatenate(radius), upr=50)
    assert form.ok, form.reason
    assert form.radius_mm == pytest.approx(R, abs=0.001)
    by_order = {h.order: h for h in form.harmonics}
    for k, a, p in lobes:
        assert by_order[k].amplitude_mm == pytest.approx(a, abs=0.0005 + 0.1 * a)
        gap = (by_order[k].phase_deg - p + 180.0) % 360.0 - 180.0
        assert abs(gap) < 10.0
    strongest = max(lobes, key=lambda x: x[1])[0]
    assert form.dominant_order == strongest
    assert form.odd_lobing == (strongest % 2 == 1)
    truth = np.zeros(3600)
    grid = np.radians(np.arange(3600) / 10.0)
    for k, a, p in lobes:
        truth += a * math.exp(-math.pi * (math.sqrt(math.log(2) / math.pi) * k / 50) ** 2) \
            * np.cos(k * grid - math.radians(p))
    ront_true = truth.max() - truth.min()
    assert form.ront_mm == pytest.approx(ront_true, abs=0.001 + 0.1 * ront_true)


def test_roundness_needs_the_revolution_covered() -> None:
    beta = np.linspace(0.0, 90.0, 500)
    out = roundness(beta, np.full(500, R))
    assert not out.ok and "cover" in out.reason


@pytest.mark.parametrize(("e_mm", "locked_deg", "concentric"), [
    (0.0, None, True), (0.01, None, False), (0.01, 105.0, False), (0.03, 0.0, False)])
def test_the_watch_tells_a_surface_off_the_spindle_from_the_rendered_frames(
        e_mm: float, locked_deg: float | None, concentric: bool) -> None:
    """Frames of the simulated rig, measured as the service does (axis with the free fit):
    the surface going round, or seen at one angle (a frame rate locked to the spindle)."""
    from drivers.sim.rig import RigConfig, ShaftRenderer, Turning
    from service.measure.diameter import MeasureParams, axis_center, measure_frame
    from service.measure.form import ConcentricityWatch
    from service.measure.geometry import geometry_of
    from service.measure.result import Method

    rig = ShaftRenderer(RigConfig(turning=Turning(e_mm, 20.0)), seed=11)
    geometry = geometry_of(rig.calibration)
    axis = axis_center(geometry)
    params = MeasureParams(reflection_check=False, free_fit=True)
    watch = ConcentricityWatch()
    for k in range(40):
        theta = 37.0 * k if locked_deg is None else locked_deg
        m = measure_frame(rig.render(31.0, k, spindle_deg=theta), geometry, Method.AXIS, params)
        if m.free_center_mm is not None:
            xx, xy, yy = m.free_center_cov
            watch.update(np.array(m.free_center_mm) - axis, np.array([[xx, xy], [xy, yy]]))
    v = watch.verdict()
    assert v.frames >= 30
    assert v.concentric is concentric, v
    if not concentric:
        assert "not concentric" in v.reason
        assert v.eccentricity_mm == pytest.approx(e_mm, rel=0.5)


def test_the_watch_needs_frames_and_forgets() -> None:
    from service.measure.form import ConcentricityWatch

    w = ConcentricityWatch(window=20, min_frames=5)
    for k in range(4):
        w.update(np.array([0.05, k * 1e-6]), np.eye(2) * 1e-5)
    assert w.verdict().concentric and "judged from 5" in w.verdict().reason
    w.update(np.array([0.05, 4e-6]), np.eye(2) * 1e-5)
    assert not w.verdict().concentric
    w.clear()
    assert w.verdict().frames == 0


def test_the_same_frames_again_are_not_counted_twice() -> None:
    """A camera replaying a ring of frames (and a measurement rate that aliases with it) shows
    the watch the same centres again: counted each time, twelve frames each 1 sigma off along
    one direction would read sqrt(40) = 6.3 sigma, not their 3.5."""
    from service.measure.form import ConcentricityWatch

    rng = np.random.default_rng(2)
    ring = [np.array([1e-3, 0.0]) + rng.normal(0.0, 1e-6, 2) for _ in range(12)]
    once, replayed = ConcentricityWatch(), ConcentricityWatch()
    for d in ring:
        once.update(d, np.eye(2) * 1e-6)
    for k in range(40):
        assert replayed.update(ring[k % 12], np.eye(2) * 1e-6) == pytest.approx(1.0, abs=0.01)
    assert once.verdict().concentric and once.verdict().offset_sigmas == pytest.approx(3.46, 0.01)
    assert replayed.verdict() == once.verdict()


def test_noise_alone_is_not_read_as_form() -> None:
    """Radii of a round surface with noise correlated along each arc (as speckle leaves
    them): the plain filtered profile's peak-to-valley is the noise's, the harmonics above
    their (correlation-inflated) uncertainty say round."""
    rng = np.random.default_rng(4)
    beta, radius = [], []
    for theta in np.arange(0.0, 360.0, 10.0):
        arc = np.linspace(-60.0, 60.0, 400) - theta
        noise = np.convolve(rng.normal(0.0, 0.004, 420), np.ones(8) / np.sqrt(8), "valid")
        beta.append(arc)
        radius.append(R + noise[:400])
    plain = roundness(np.concatenate(beta), np.concatenate(radius), significance=0.0)
    judged = roundness(np.concatenate(beta), np.concatenate(radius), correlation=None)
    assert plain.ront_mm > 0.003
    assert judged.ront_mm < 0.001 and judged.dominant_order == 0
    assert judged.ront_uncertainty_mm > plain.ront_uncertainty_mm  # the correlation counts


def lobed_frames(lobes, frames_n: int, offset_mm: float, noise_mm: float, seed: int,
                 arc_deg: float = 110.0, n: int = 300):
    """Frames of radii about the surface's centre on arcs at turning material angles, each
    frame's radii shifted by its own error (a frame's diameter error), with noise."""
    rng = np.random.default_rng(seed)
    out = []
    for j in range(frames_n):
        start = (37.0 * j) % 360.0
        beta = np.radians(start + np.linspace(0.0, arc_deg, n))
        r = R + sum(a * np.cos(k * beta - math.radians(p)) for k, a, p in lobes)
        out.append((beta, r + rng.normal(0.0, offset_mm) + rng.normal(0.0, noise_mm, n)))
    return out


def test_each_frames_own_radius_error_comes_out_of_the_form() -> None:
    """Five lobes of 1.5 um under frames whose radii are each 5 um off (a frame's diameter
    error): pooled as one set of points, the frames' errors are noise over the material's
    angle and bury the lobes; with each frame's own mean, the lobes come out whole (the
    arcs' means of each harmonic are kept in the normal equations)."""
    from service.measure.form import form_of_frames

    lobes = [(5, 0.0015, 200.0), (2, 0.002, 40.0)]
    data = lobed_frames(lobes, 150, 0.005, 0.004, seed=3)
    got = form_of_frames(data, upr=50)
    pooled = roundness(np.degrees(np.concatenate([b for b, _ in data])),
                       np.concatenate([r for _, r in data]), correlation=None)
    assert got.ok, got.reason
    by_order = {h.order: h for h in got.harmonics}
    for k, a, p in lobes:
        h = by_order[k]
        assert h.amplitude_mm == pytest.approx(a, abs=4.0 * h.amplitude_uncertainty_mm)
        assert h.amplitude_mm > 4.5 * h.amplitude_uncertainty_mm
        gap = (h.phase_deg - p + 180.0) % 360.0 - 180.0
        assert abs(gap) < 10.0
    assert got.dominant_order == 2
    assert got.radius_mm == pytest.approx(R, abs=0.001)
    assert {h.order for h in got.harmonics
            if h.amplitude_mm > 4.5 * h.amplitude_uncertainty_mm} == {2, 5}
    pooled_5 = {h.order: h for h in pooled.harmonics}[5]
    assert pooled_5.amplitude_uncertainty_mm > 3.0 * by_order[5].amplitude_uncertainty_mm


def test_frames_must_cover_the_revolution() -> None:
    from service.measure.form import form_of_frames

    assert not form_of_frames([]).ok
    short = [(b * 0.25, r) for b, r in lobed_frames([], 10, 0.0, 0.001, seed=2, arc_deg=20.0)]
    assert "cover" in form_of_frames(short).reason
