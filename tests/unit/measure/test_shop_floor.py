"""The shop floor: the simulated rig's disturbances, and what the extractor and the fits do
about them (blob rejection, the top-hat coarse pass, the noise estimate, the section's
consensus, the refusal of uncertain diameters, the tracker's gate)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from drivers.sim.disturb import FAMILIES, Disturbances, Ghost, Glints
from drivers.sim.rig import RigConfig, ShaftRenderer
from service.measure import consensus
from service.measure import steger_kernels as sk
from service.measure.axis_track import AxisTracker
from service.measure.diameter import MeasureParams, measure_frame
from service.measure.geometry import geometry_of
from service.measure.result import Method, Status
from service.measure.stripe import StripeParams, extract_stripe


def test_disturbances_are_seeded_and_leave_the_clean_twin_alone() -> None:
    clean = ShaftRenderer(RigConfig(), seed=5).render(30.0, 2)
    off = ShaftRenderer(RigConfig(disturbances=Disturbances()), seed=5).render(30.0, 2)
    assert np.array_equal(clean, off)
    for name, spec in FAMILIES.items():
        if name == "clean":
            continue
        a = ShaftRenderer(RigConfig(disturbances=spec), seed=5).render(30.0, 2)
        b = ShaftRenderer(RigConfig(disturbances=spec), seed=5).render(30.0, 2)
        assert np.array_equal(a, b), name
        assert not np.array_equal(a, clean), name


def test_disturbances_from_a_dict_name_what_is_unknown() -> None:
    spec = Disturbances.from_dict({"glints": {"count": 4, "sigma_px": [1, 2]}, "exposure": 2})
    assert spec.glints.count == 4 and spec.glints.sigma_px == (1, 2) and spec.exposure == 2.0
    with pytest.raises(ValueError, match="unknown disturbance 'smoke'"):
        Disturbances.from_dict({"smoke": {}})
    with pytest.raises(ValueError, match="unknown glints setting"):
        Disturbances.from_dict({"glints": {"colour": 1}})


def test_feed_marks_ripple_the_stripe_but_not_its_circle() -> None:
    """A 4 um helical ripple moves the stripe's section points about the circle; the fit
    averages it out."""
    spec = Disturbances.from_dict({"feed_marks": {"amplitude_um": 4.0, "period_mm": 0.1}})
    r = ShaftRenderer(RigConfig(disturbances=spec), seed=3)
    g = geometry_of(r.calibration)
    errs = [measure_frame(r.render(30.0, i), g).diameter_mm - 30.0 for i in range(4)]
    assert np.mean(np.abs(errs)) < 0.004, errs


def _blobs(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    img = np.full((300, 300), 6.0, np.float32)
    yy, xx = np.mgrid[0:300, 0:300]
    for x, y, s in zip(rng.uniform(20, 280, n), rng.uniform(20, 280, n), rng.uniform(1, 2.5, n),
                       strict=True):
        img += 200 * np.exp(-((xx - x) ** 2 + (yy - y) ** 2) / (2 * s**2))
    img += rng.normal(0, 1.2, img.shape)
    return np.clip(img, 0, 255).astype(np.uint8)


def test_glints_are_not_lines() -> None:
    """Steger's test passes all over a blob's shoulder (the Hessian looks like a line running
    outward there): its centres fill a patch, which is not kept as a line."""
    img = _blobs(30, 1)
    assert len(extract_stripe(img, StripeParams())) == 0
    assert len(extract_stripe(img, StripeParams(max_chain_density=math.inf))) > 300


@pytest.mark.parametrize(("contrast", "grain"), [(0.1, 0.8), (0.5, 0.8), (0.5, 2.0)])
def test_a_speckled_stripe_is_a_line_not_a_patch(contrast: float, grain: float) -> None:
    r = ShaftRenderer(RigConfig(speckle_contrast=contrast, speckle_grain_px=grain), seed=2)
    img = r.render(30.0, 0)
    every = extract_stripe(img, StripeParams(max_chain_density=math.inf))
    assert len(extract_stripe(img)) == len(every) > 300


@pytest.mark.parametrize("family", ["glints", "droplets", "background", "overexposed"])
def test_axis_measures_through_the_disturbance(family: str) -> None:
    r = ShaftRenderer(RigConfig(disturbances=FAMILIES[family]), seed=11)
    g = geometry_of(r.calibration)
    for i, d in enumerate((21.7, 30.0, 44.0)):
        m = measure_frame(r.render(d, i), g)
        assert m.status is Status.OK, (family, d, m.reason)
        assert abs(m.diameter_mm - d) < 0.008, (family, d, m.diameter_mm)


def test_a_bright_machine_edge_is_not_the_stripe() -> None:
    """A lit band crossing the frame (sharp sides: Steger sees lines along them) and a light
    gradient: the top-hat coarse pass and the section's consensus keep to the stripe."""
    spec = Disturbances.from_dict({"background": {"edge_dn": 120.0, "gradient_dn": 50.0,
                                                  "edge_width_px": [12, 30]}})
    r = ShaftRenderer(RigConfig(disturbances=spec), seed=12)
    g = geometry_of(r.calibration)
    for i in range(4):
        m = measure_frame(r.render(30.0, i), g)
        assert m.status is Status.OK, m.reason
        assert abs(m.diameter_mm - 30.0) < 0.008


def test_a_narrow_lit_edge_with_more_centres_than_the_stripe_does_not_set_its_width() -> None:
    """A lit band 8-10 px wide crossing the frame is a line to Steger, nine pixels wide, with
    five times the stripe's centres: their median width had every stripe centre dropped as
    "too narrow" (0 of 1640 centres on the shaft's circle)."""
    spec = Disturbances.from_dict({"background": {"edge_dn": 140.0,
                                                  "edge_width_px": [8, 10]}})
    r = ShaftRenderer(RigConfig(disturbances=spec), seed=901)
    clean = extract_stripe(ShaftRenderer(RigConfig(), seed=901).render(21.7, 1))
    found = extract_stripe(r.render(21.7, 1))
    d = np.min(np.hypot(*(found.xy[:, None, :] - clean.xy[None, :, :]).transpose(2, 0, 1)),
               axis=1)
    assert (d < 1.0).sum() > 0.5 * len(clean), ((d < 1.0).sum(), len(clean))
    assert (d < 1.0).mean() > 0.8  # and the edge's wide centres are gone


def test_noise_is_the_pixels_not_the_light_gradient() -> None:
    rng = np.random.default_rng(2)
    yy, xx = np.mgrid[0:1024, 0:1376].astype(np.float32)
    flat = 20 + 1.5 * rng.standard_normal((1024, 1376)).astype(np.float32)
    sloped = flat + 60 * xx / 1376 + 40 * (yy > 600)
    _, n_flat = sk.background_and_noise(flat, 4, 8)
    _, n_sloped = sk.background_and_noise(sloped, 4, 8)
    assert n_flat == pytest.approx(1.5, rel=0.08)
    assert n_sloped == pytest.approx(n_flat, rel=0.08)


def _arc(n: int, r: float, c=(0.0, 0.0), a0=0.3, a1=2.0, noise=0.002, seed=0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    a = rng.uniform(a0, a1, n)
    return np.column_stack([c[0] + r * np.cos(a), c[1] + r * np.sin(a)]) \
        + rng.normal(0, noise, (n, 2))


def test_ring_consensus_takes_the_circle_about_the_axis() -> None:
    stripe = _arc(300, 15.0)
    ghost = _arc(150, 15.4, seed=1)        # a ghost 0.4 mm out
    edge = np.column_stack([np.linspace(-5, 20, 200), np.linspace(30, -5, 200)])
    pts = np.vstack([stripe, ghost, edge])
    keep = consensus.ring_consensus(pts, np.zeros(2), 0.05)
    assert keep[:300].mean() > 0.99 and keep[300:450].sum() == 0 and keep[450:].sum() < 10


def test_circle_consensus_finds_the_shaft_among_more_outliers_than_points() -> None:
    stripe = _arc(200, 12.0, c=(3.0, -2.0))
    rng = np.random.default_rng(4)
    clutter = rng.uniform(-20, 20, (300, 2))
    keep = consensus.circle_consensus(np.vstack([stripe, clutter]), 0.02, 500.0)
    assert keep[:200].mean() > 0.95 and keep[200:].mean() < 0.05


def test_a_chain_mostly_off_the_circle_goes_whole() -> None:
    inside = np.array([True, True, True, False, True, False, False, True])
    chain = np.array([0, 0, 0, 0, 1, 1, 1, 2])
    assert list(consensus.by_chain(inside, chain)) == [True, True, True, False, False,
                                                      False, False, True]
    assert list(consensus.by_chain(inside, None)) == list(inside)


def test_a_long_stretch_on_the_circle_stays_whatever_its_chain_runs_into() -> None:
    """A large drop's rim links to the stripe on both sides of it: 45 % of the chain on the
    circle (138 of 302 centres in a held-out frame) is still the stripe."""
    inside = np.r_[np.ones(40, bool), np.zeros(60, bool), np.ones(3, bool), np.zeros(20, bool)]
    chain = np.r_[np.zeros(100, int), np.ones(23, int)]
    keep = consensus.by_chain(inside, chain)
    assert keep[:40].all() and not keep[40:].any()  # the crossing line's three points go


def test_a_drop_larger_than_the_stripe_is_wide_does_not_take_the_stripe_with_it() -> None:
    spec = Disturbances.from_dict({"droplets": {"count": 5, "radius_px": [3.0, 10.0]}})
    r = ShaftRenderer(RigConfig(disturbances=spec), seed=903)
    m = measure_frame(r.render(21.7, 3), geometry_of(r.calibration))
    assert m.status is Status.OK, m.reason
    assert abs(m.diameter_mm - 21.7) < 0.008


def test_uncertain_diameters_are_refused_with_the_figure() -> None:
    r = ShaftRenderer(RigConfig(), seed=4)
    g = geometry_of(r.calibration)
    strict = measure_frame(r.render(30.0), g, Method.AXIS, MeasureParams(
        max_uncertainty_mm=0.0005))
    assert strict.status is Status.UNCERTAIN and "limit 0.5 um" in strict.reason
    assert strict.diameter_mm is None and strict.uncertainty_mm > 0.0005


def test_glints_never_make_a_confident_wrong_diameter() -> None:
    """Many glints (a chip shower): every frame is either refused or within 20 um, by both
    methods."""
    spec = Disturbances(glints=Glints(count=25, spread_px=20.0, on_stripe=0.5))
    r = ShaftRenderer(RigConfig(disturbances=spec), seed=13)
    g = geometry_of(r.calibration)
    for i in range(4):
        img = r.render(30.0, i)
        for method in (Method.AXIS, Method.GEOMETRIC):
            m = measure_frame(img, g, method)
            assert not m or abs(m.diameter_mm - 30.0) < 0.020, (method, m.diameter_mm)


def test_the_tracker_does_not_take_a_stray_free_centre_into_its_reference() -> None:
    t = AxisTracker(np.zeros(2), base_sigma_mm=0.001, reference_frames=5)
    cov = np.diag([1e-4, 1e-6])            # 10 um along the bisector, 1 um across
    assert not t.update(np.array([0.0, 0.05]), cov, 30.0)   # 50 um across: astray
    for _ in range(5):
        assert t.update(np.array([0.002, 0.0]), cov, 30.0)
    assert t.rejected == 1 and math.isfinite(t.center()[1])


def test_a_frame_whose_points_are_all_off_the_circle_is_refused_quietly(recwarn) -> None:
    """Lines that are not the shaft's (here: two straight bright bars) leave no arc on the
    circle about the axis: refused, said so, and no warning on the way. (Where a bar runs
    tangent to a circle about the axis some 30 of its centres lie on that circle, a stretch
    that ``consensus.by_chain`` keeps: over 6 degrees of arc, refused as too short.)"""
    r = ShaftRenderer(RigConfig(), seed=1)
    g = geometry_of(r.calibration)
    img = np.full((1024, 1376), 5, np.uint8)
    img[100:900, 200:202] = 160
    img[300:302, 300:1200] = 160
    m = measure_frame(img, g)
    assert m.diameter_mm is None
    assert (m.status is Status.TOO_FEW_POINTS and "lie on one circle" in m.reason) or (
        m.status is Status.ARC_TOO_SHORT and "degrees of the section" in m.reason), m.reason
    assert not [w for w in recwarn if issubclass(w.category, RuntimeWarning)]


def test_an_uncertain_frame_still_says_where_the_stripe_is() -> None:
    """The next frame looks near it (and the camera's region follows it): a free circle
    refused as uncertain frame after frame must not make every frame a full search."""
    r = ShaftRenderer(RigConfig(), seed=4)
    g = geometry_of(r.calibration)
    m = measure_frame(r.render(30.0), g, Method.GEOMETRIC)
    assert m.status is Status.UNCERTAIN and m.stripe_px is not None and len(m.stripe_px) > 100
    blank = measure_frame(np.full((1024, 1376), 5, np.uint8), g)
    assert blank.stripe_px is None


def _line(offset_px: float | None, gain: float = 0.35) -> np.ndarray:
    """A vertical Gaussian line at x = 50.3 (sigma 1.2 px, 150 DN) on 10 DN, with a second,
    fainter one ``offset_px`` to its right."""
    x = np.arange(120, dtype=np.float32)
    row = 10 + 150 * np.exp(-0.5 * ((x - 50.3) / 1.2) ** 2)
    if offset_px is not None:
        row += gain * 150 * np.exp(-0.5 * ((x - 50.3 - offset_px) / 1.6) ** 2)
    return np.tile(row, (80, 1)).astype(np.float32)


@pytest.mark.parametrize(("offset", "lopsided"), [(None, False), (3.0, True), (5.0, True),
                                                  (-4.0, True), (12.0, False)])
def test_a_second_line_beside_the_stripe_makes_it_lopsided(offset, lopsided) -> None:
    img = _line(offset)
    ys = np.arange(20, 60, dtype=np.float64)
    b = sk.side_balance(img - 10, np.full_like(ys, 50.3), ys, np.ones_like(ys),
                        np.zeros_like(ys), np.full_like(ys, 150.0))
    assert bool(np.median(np.abs(b)) > 0.05) == lopsided, b[:3]
    # The level under the line cancels: one side less the other.
    assert np.allclose(b, sk.side_balance(img, np.full_like(ys, 50.3), ys, np.ones_like(ys),
                                          np.zeros_like(ys), np.full_like(ys, 150.0)))


@pytest.mark.parametrize("offset", [(3.0, 0.0), (-4.0, 4.0), (2.0, 2.0)])
def test_a_reflection_beside_the_stripe_is_measured_through(offset) -> None:
    """A ghost within the filters' reach pulls the centres by tenths of a pixel (42 um of
    diameter at 3 px, with an uncertainty of 3 um): the reflection is modelled from the
    stripe's profiles and its pull taken out (``service.measure.reflection``)."""
    spec = Disturbances(ghost=Ghost(gain=0.2, offset_px=offset))
    r = ShaftRenderer(RigConfig(disturbances=spec), seed=12)
    m = measure_frame(r.render(30.0, 1), geometry_of(r.calibration))
    assert m.status is Status.OK, m.reason
    assert abs(m.diameter_mm - 30.0) < 0.005, m.diameter_mm
    assert m.reflection_px is not None and math.dist(m.reflection_px, offset) < 1.0
    assert "a reflection at" in m.note and m.uncertainty_mm < 0.0065


def test_a_second_line_as_bright_as_the_stripe_is_refused() -> None:
    spec = Disturbances(ghost=Ghost(gain=1.6, offset_px=(3.0, 0.0)))
    r = ShaftRenderer(RigConfig(disturbances=spec), seed=12)
    m = measure_frame(r.render(30.0, 1), geometry_of(r.calibration))
    assert m.status is Status.UNCERTAIN and "lopsided" in m.reason, (m.status, m.reason)
    assert "which one is the stripe" in m.reason, m.reason
    assert m.stripe_px is not None  # still tracked


def test_a_faint_reflection_within_the_lopsidedness_limit_is_found() -> None:
    """A reflection a seventh of the stripe's height 2 px off leaves the profile within the
    lopsidedness limit but moves the diameter by about 20 um: the check on every frame finds
    it (the service asks it a few times a second, ``service.measure.cadence``)."""
    spec = Disturbances(ghost=Ghost(gain=0.15, offset_px=(2.0, 0.0), blur_px=1.0))
    r = ShaftRenderer(RigConfig(disturbances=spec), seed=5)
    g, img = geometry_of(r.calibration), r.render(21.7, 0)
    unchecked = measure_frame(img, g, params=MeasureParams(reflection_check=False))
    assert unchecked.status is Status.OK and abs(unchecked.diameter_mm - 21.7) > 0.012
    m = measure_frame(img, g)
    assert m.status is Status.OK and abs(m.diameter_mm - 21.7) < 0.005, m.diameter_mm
    assert m.reflection_px is not None


@pytest.mark.parametrize("changes", [{}, {"sheet_sigma_mm": 0.15}, {"peak_dn": 60.0},
                                     {"speckle_contrast": 0.5}, {"speckle_grain_px": 2.0}])
def test_a_stripe_alone_is_not_lopsided(changes) -> None:
    r = ShaftRenderer(RigConfig().with_(**changes), seed=3)
    g = geometry_of(r.calibration)
    for i in range(2):
        m = measure_frame(r.render(27.0, i), g)
        assert "lopsided" not in m.reason, (changes, m.reason)


def test_noise_alone_does_not_make_a_stripe_lopsided() -> None:
    """The paper's added noise (sigma 25.5 DN): the limit grows with noise over height."""
    r = ShaftRenderer(RigConfig(), seed=3)
    g = geometry_of(r.calibration)
    rng = np.random.default_rng(0)
    img = np.clip(np.rint(r.render(30.0) + rng.normal(0, 25.5, (1024, 1376))), 0, 255)
    m = measure_frame(img.astype(np.uint8), g)
    assert "lopsided" not in m.reason, m.reason


def test_the_ring_widens_to_the_scatter_of_a_thick_sheet() -> None:
    """Points scattered 30 um about their ring (a thick sheet under speckle): a 50 um window
    would cut a tenth of them, the tails of their own scatter; the ring widens to four of
    their robust sigmas, and a second ring 0.3 mm off (a ghost) stays out."""
    rng = np.random.default_rng(5)
    t = np.linspace(0.5, 2.2, 500)
    ring = (15.0 + rng.normal(0.0, 0.030, t.size))[:, None] * np.column_stack(
        [np.cos(t), np.sin(t)])
    ghost = 15.3 * np.column_stack([np.cos(t[::5]), np.sin(t[::5])])
    keep = consensus.ring_consensus(np.vstack([ring, ghost]), np.zeros(2), 0.05)
    assert keep[:500].mean() > 0.995 and not keep[500:].any()
    fixed = consensus.ring_consensus(np.vstack([ring, ghost]), np.zeros(2), 0.05,
                                     scatter_sigmas=0.0)
    assert 0.85 < fixed[:500].mean() < 0.95 and not fixed[500:].any()
    # A thin sheet's ring (8 um) keeps the window as it is.
    thin = (15.0 + rng.normal(0.0, 0.008, t.size))[:, None] * np.column_stack(
        [np.cos(t), np.sin(t)])
    assert np.array_equal(consensus.ring_consensus(thin, np.zeros(2), 0.05),
                          consensus.ring_consensus(thin, np.zeros(2), 0.05, scatter_sigmas=0))


def test_a_thick_sheet_is_measured_with_filters_that_suit_it() -> None:
    """A sheet of sigma 0.10 mm makes a stripe 1.6 px wide: with 1.5 px filters the
    diameter follows the speckle grains inside the stripe's core; with filters to suit the
    stripe it scatters less (here 3.2 against 2.6 um; over 40 frames 4.1 against 3.3)."""
    r = ShaftRenderer(RigConfig(sheet_sigma_mm=0.10), seed=21)
    g = geometry_of(r.calibration)
    narrow = MeasureParams(reflection_check=False, stripe=StripeParams(scale_per_width=0.0))
    suited = MeasureParams(reflection_check=False)
    e_narrow, e_suited = [], []
    for i in range(10):
        img = r.render(30.0, i)
        e_narrow.append(measure_frame(img, g, Method.AXIS, narrow).diameter_mm - 30.0)
        e_suited.append(measure_frame(img, g, Method.AXIS, suited).diameter_mm - 30.0)
    assert np.std(e_suited) < 0.9 * np.std(e_narrow), (np.std(e_suited), np.std(e_narrow))


def test_a_lopsided_stripes_ring_does_not_widen() -> None:
    """A ghost's pull scatters the stripe's points too, but that is a second line, not the
    stripe's own scatter: the ring stays as wide as ``consensus_mm``."""
    from service.measure.diameter import axis_center, on_the_shaft, section_points

    r = ShaftRenderer(RigConfig(disturbances=FAMILIES["ghost"]), seed=12)
    g = geometry_of(r.calibration)
    known = (axis_center(g), 0.001)
    points = section_points(extract_stripe(r.render(30.0, 1)), g)
    fixed = MeasureParams(consensus_sigmas=0.0)
    assert np.array_equal(on_the_shaft(points, MeasureParams(), known).section,
                          on_the_shaft(points, fixed, known).section)
    thick = ShaftRenderer(RigConfig(sheet_sigma_mm=0.15), seed=12)
    g = geometry_of(thick.calibration)
    points = section_points(extract_stripe(thick.render(30.0, 1)), g)
    assert len(on_the_shaft(points, MeasureParams(), known).section) > \
        len(on_the_shaft(points, fixed, known).section)


def test_a_wide_stripe_is_extracted_once_at_the_scale_the_last_frame_found(monkeypatch) -> None:
    """Tracked as the service tracks it (the last frame's centres and filter scale), a thick
    sheet's stripe is extracted once a frame, at the matched scale, and measured as the full
    path measures it (to a tenth of its uncertainty: the band about the last frame's centres
    is not the band about this frame's first ones, and the background is estimated over
    it); a frame checked for a reflection, or a stripe that no longer suits the scale, goes
    the full path."""
    from service.measure import diameter

    r = ShaftRenderer(RigConfig(sheet_sigma_mm=0.12, speckle_grain_px=1.6), seed=4)
    g = geometry_of(r.calibration)
    params = MeasureParams(reflection_check=False)
    calls: list[float] = []
    real = diameter.extract_stripe
    monkeypatch.setattr(diameter, "extract_stripe",
                        lambda image, p, near=None: calls.append(p.sigma_px)
                        or real(image, p, near))
    first = measure_frame(r.render(30.0, 0), g, Method.AXIS, params)
    assert first and first.filter_px > params.stripe.sigma_px, first
    near, scale = first.stripe_px, first.filter_px
    for i in range(1, 6):
        img = r.render(30.0, i)
        calls.clear()
        hinted = measure_frame(img, g, Method.AXIS, params, near=near, scale_px=scale)
        assert calls == [scale], calls
        full = measure_frame(img, g, Method.AXIS, params, near=near)
        assert hinted.status is full.status is Status.OK
        assert abs(hinted.diameter_mm - full.diameter_mm) < 0.1 * full.uncertainty_mm, \
            (hinted.diameter_mm, full.diameter_mm, full.uncertainty_mm)
        near, scale = hinted.stripe_px, hinted.filter_px
    calls.clear()
    checked = replace(params, reflection_check=True)
    measure_frame(img, g, Method.AXIS, checked, near=near, scale_px=scale)
    assert calls[0] == params.stripe.sigma_px, calls
    # The default rig's narrow stripe does not suit the wide scale: measured afresh.
    plain = ShaftRenderer(RigConfig(), seed=4)
    gp = geometry_of(plain.calibration)
    img = plain.render(30.0, 1)
    calls.clear()
    again = measure_frame(img, gp, Method.AXIS, params, scale_px=2.5)
    assert calls == [2.5, params.stripe.sigma_px], calls
    assert again.filter_px == params.stripe.sigma_px
    assert again.diameter_mm == measure_frame(img, gp, Method.AXIS, params).diameter_mm
