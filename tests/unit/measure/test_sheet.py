"""The light sheet's thickness model (``service.measure.sheet``) against analytic truth and
the simulated rig."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drivers.sim.rig import RigConfig, ShaftRenderer
from service.measure.diameter import MeasureParams, axis_center, measure_frame
from service.measure.geometry import geometry_of
from service.measure.result import Method
from service.measure.section import orthonormal_basis
from service.measure.sheet import (
    cross_the_stripe,
    light_direction,
    ridge_bias,
    sheet_sigma_from_profile,
)

SMOOTHING = math.hypot(1.5, 0.7)


def radial_bias(center, radius: float, angles, geometry, sigma_mm: float) -> np.ndarray:
    """The model's radial error (mm) at ``angles``, as the measurement runs it."""
    crossings = cross_the_stripe(center, radius, angles, geometry, SMOOTHING)
    return ridge_bias(crossings, geometry, center, radius, sigma_mm, SMOOTHING)


@pytest.fixture(scope="module")
def rig():
    r = ShaftRenderer(RigConfig(laser_azimuth_deg=20.0, speckle_contrast=0.0), seed=1)
    return r, geometry_of(r.calibration)


def arc(geometry, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """The section centre and sample angles over the arc the camera sees (around 180 deg)."""
    c = axis_center(geometry)
    return c, np.radians(np.linspace(130.0, 230.0, 24))


def test_a_thin_sheet_leaves_no_error(rig) -> None:
    _, geo = rig
    c, ang = arc(geo, 18.0)
    assert np.all(radial_bias(c, 18.0, ang, geo, 0.0) == 0)
    thin = radial_bias(c, 18.0, ang, geo, 0.003)
    assert np.nanmax(np.abs(thin)) < 1e-5  # 0.01 um


def test_the_error_grows_with_the_square_of_the_thickness(rig) -> None:
    _, geo = rig
    c, ang = arc(geo, 18.0)
    a = radial_bias(c, 18.0, ang, geo, 0.03)
    b = radial_bias(c, 18.0, ang, geo, 0.06)
    big = np.abs(b) > 2e-4
    assert big.sum() > 3
    assert np.median(b[big] / a[big]) == pytest.approx(4.0, rel=0.2)
    # Inward, and most where the camera looks obliquely (the arc's ends).
    assert np.nanmean(b) < 0 and abs(b[0]) > abs(b[12]) and abs(b[-1]) > abs(b[12])


def test_sheet_sigma_from_the_profile() -> None:
    slope = np.full(60, 0.08)  # mm per px
    w2 = (0.06 / slope) ** 2 + 0.7**2  # the image width, blur included
    curvature = np.random.default_rng(1).uniform(20, 40, 60)
    peak = curvature * (w2 + 1.5**2)
    assert sheet_sigma_from_profile(peak, curvature, slope, 1.5, 0.7) == pytest.approx(0.06)
    assert math.isnan(sheet_sigma_from_profile(peak * 0.1, curvature, slope, 1.5, 0.7))


def test_sheet_sigma_on_rendered_images(rig) -> None:
    """The estimate on a noise-free image of the simulated rig, whose sheet has sigma 0.06."""
    r, geo = rig
    seen = {}
    import service.measure.sheet_correction as diameter

    def spy(*args: object) -> float:
        seen["sigma"] = sheet_sigma_from_profile(*args)
        return seen["sigma"]

    original, diameter.sheet_sigma_from_profile = diameter.sheet_sigma_from_profile, spy
    try:
        assert measure_frame(r.render_clean(36.0) + 3.0, geo, Method.AXIS)
    finally:
        diameter.sheet_sigma_from_profile = original
    assert seen["sigma"] == pytest.approx(0.06, rel=0.05)


def test_light_direction_from_brightness(rig) -> None:
    _, geo = rig
    c = axis_center(geo)
    ang = np.radians(np.linspace(120.0, 240.0, 200))
    section = c + 18.0 * np.column_stack([np.cos(ang), np.sin(ang)])
    e1, e2 = orthonormal_basis(geo.axis_direction)
    normals = np.cos(ang)[:, None] * e1 + np.sin(ang)[:, None] * e2
    n = geo.plane_normal
    truth = normals[100] - (normals[100] @ n) * n + 0.3 * np.cross(n, normals[100])
    truth /= np.linalg.norm(truth)
    rng = np.random.default_rng(4)
    brightness = 150 * np.clip(normals @ truth, 0, None) * (1 + 0.05 * rng.standard_normal(200))
    got = light_direction(section, c, brightness, geo)
    assert got is not None
    assert math.degrees(math.acos(min(1.0, float(got @ truth)))) < 2.0
    assert light_direction(section[:5], c, brightness[:5], geo) is None


@pytest.mark.parametrize("az, diameter", [(20.0, 36.0), (47.0, 28.0), (60.0, 44.0)])
def test_the_correction_takes_out_most_of_the_error(az: float, diameter: float) -> None:
    """Noise-free images of the simulated rig, centre held on the axis: the systematic error
    of the stripe centres, with and without the model. Without weighting by the scatter
    along the arc: on a noise-free image the residuals are the model's own error, not
    scatter, and weights from them would choose which part of it is left."""
    r = ShaftRenderer(RigConfig(laser_azimuth_deg=az, speckle_contrast=0.0), seed=1)
    geo = geometry_of(r.calibration)
    img = r.render_clean(diameter) + 3.0
    held = dict(axis_sigma_mm=1e-5, arc_weighting=False)
    off = measure_frame(img, geo, Method.AXIS, MeasureParams(sheet_correction=False, **held))
    on = measure_frame(img, geo, Method.AXIS, MeasureParams(**held))
    assert off and on
    e_off, e_on = off.diameter_mm - diameter, on.diameter_mm - diameter
    assert abs(e_on) < 0.5 * abs(e_off), (e_off, e_on)


def test_kept_sheet_model_matches_the_exact_evaluation(rig) -> None:
    """The correction from the kept grid of the model against the model evaluated at the
    fitted circle itself, densely (64 samples over the arc; the estimated thickness)."""
    import service.measure.sheet_correction as sc
    from service.measure import fit as fits
    from service.measure.diameter import MeasureParams, drop_grazing, section_points
    from service.measure.sheet import arc_angles
    from service.measure.stripe import extract_stripe

    r, geo = rig
    params = MeasureParams()
    worst = points = 0.0
    for d in (21.3, 33.8, 45.1):
        pts = drop_grazing(section_points(extract_stripe(r.render(d, 2)), geo), geo, params)
        circ = fits.fit_geometric(pts.section)
        kept = sc.correct_sheet_bias(pts, circ.center, circ.radius, geo, params)
        st, smoothing = pts.stripe, float(np.hypot(params.stripe.sigma_px, 0.7))
        angles, _ = arc_angles(pts.section, circ.center)
        samples = np.linspace(angles.min(), angles.max(), 64)
        crossings = cross_the_stripe(circ.center, circ.radius, samples, geo, smoothing)
        order = np.argsort(angles)
        with np.errstate(divide="ignore", invalid="ignore"):
            brightness = st.peak * np.sqrt(st.width_px**2 + 1.5**2) / st.width_px
        slope = np.interp(angles, samples, crossings.slope_mm_per_px)
        sigma = sheet_sigma_from_profile(st.peak[order], st.strength[order], slope[order],
                                         1.5, 0.7)
        radial = ridge_bias(crossings, geo, circ.center, circ.radius, sigma, smoothing,
                            light_direction(pts.section, circ.center, brightness, geo))
        known = np.isfinite(radial)
        dr = np.interp(angles, samples[known], radial[known])
        rel = pts.section - circ.center
        dist = np.hypot(rel[:, 0], rel[:, 1])
        exact = circ.center + rel * ((dist - dr) / dist)[:, None]
        points = max(points, float(np.abs(np.hypot(*(kept - circ.center).T)
                                          - np.hypot(*(exact - circ.center).T)).max()))
        worst = max(worst, abs(fits.fit_geometric(kept).radius
                               - fits.fit_geometric(exact).radius))
    # mm; the corrections themselves are about a micrometre
    # Measured: 19 nm at a point, 14 nm on the radius (16 samples, as before the model's
    # answers were kept, were 50 nm off on the radius).
    assert points < 5e-5, points   # any point: under 50 nm
    assert worst < 2e-5, worst     # the fitted radius: under 20 nm
