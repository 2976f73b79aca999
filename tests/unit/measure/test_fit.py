"""Fits against points from a known circle or ellipse, with seeded noise, on 60-120 degree arcs."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from service.measure import fit as F  # noqa: N812  (F for the fit module, as in the paper)

CIRCLE_FITS = {
    "kasa": F.fit_kasa, "hyper": F.fit_hyper, "geometric": F.fit_geometric, "paper": F.fit_paper,
}


def arc_points(radius: float, arc_deg: float, n: int, sigma: float = 0.0, seed: int = 0,
               center: tuple[float, float] | None = None) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    c = np.array(center) if center is not None else rng.uniform(-50, 50, 2)
    t = rng.uniform(0, 2 * np.pi) + np.linspace(0, math.radians(arc_deg), n)
    pts = c + radius * np.column_stack([np.cos(t), np.sin(t)])
    return pts + rng.normal(0, sigma, pts.shape), c


@pytest.mark.parametrize("name", CIRCLE_FITS)
@pytest.mark.parametrize("arc", [60, 90, 120])
def test_exact_points_give_the_exact_circle(name: str, arc: float) -> None:
    pts, c = arc_points(17.3, arc, 200, seed=arc)
    fit = CIRCLE_FITS[name](pts)
    assert fit
    assert fit.radius == pytest.approx(17.3, rel=1e-9)
    assert np.allclose(fit.center, c, atol=1e-7)
    assert fit.rms < 1e-9


# Bounds for sigma = 5 um and N = 300 points: the radius's standard deviation measured over 200
# seeds is 5.7, 2.6 and 1.5 um on arcs of 60, 90 and 120 degrees for every fit.
@pytest.mark.parametrize("name", CIRCLE_FITS)
@pytest.mark.parametrize(("arc", "std_um"), [(60, 5.7), (90, 2.6), (120, 1.5)])
def test_noisy_arcs_recover_the_radius_to_theory(name: str, arc: float, std_um: float) -> None:
    errs = []
    for seed in range(40):
        pts, _ = arc_points(15.0, arc, 300, sigma=0.005, seed=seed)
        fit = CIRCLE_FITS[name](pts)
        assert fit, fit.reason
        errs.append(fit.radius - 15.0)
    errs_um = np.array(errs) * 1000
    assert abs(errs_um.mean()) < 3 * std_um / math.sqrt(len(errs)) + 1.5  # Kasa: small bias
    assert errs_um.std() < 1.5 * std_um


def test_kasa_is_biased_low_on_short_noisy_arcs_and_geometric_is_not() -> None:
    kasa, geo = [], []
    for seed in range(60):
        pts, _ = arc_points(10.0, 60, 200, sigma=0.03, seed=seed)
        kasa.append(F.fit_kasa(pts).radius - 10.0)
        geo.append(F.fit_geometric(pts).radius - 10.0)
    # Known result: Kasa shrinks the radius by about sigma^2 terms amplified on short arcs.
    assert np.mean(kasa) < np.mean(geo) - 0.01
    assert abs(np.mean(geo)) < 0.02


def test_geometric_fit_rejects_gross_outliers() -> None:
    pts, c = arc_points(20.0, 100, 300, sigma=0.004, seed=11)
    rng = np.random.default_rng(5)
    bad = rng.choice(300, 30, replace=False)
    pts[bad] += rng.choice([-1, 1], (30, 1)) * rng.uniform(0.2, 1.0, (30, 1)) * (pts[bad] - c) / 20
    fit = F.fit_geometric(pts)
    assert fit
    assert abs(fit.radius - 20.0) < 0.003
    assert not fit.inliers[bad].any()
    assert fit.inliers.sum() >= 260
    # Without rejection the outliers pull a plain algebraic fit far off.
    assert abs(F.fit_kasa(pts).radius - 20.0) > 0.01


@pytest.mark.parametrize("name", CIRCLE_FITS)
def test_too_few_points_is_a_falsy_failure_with_reason(name: str) -> None:
    fit = CIRCLE_FITS[name](np.array([[0.0, 1.0], [1.0, 0.0]]))
    assert not fit
    assert "points" in fit.reason
    assert math.isnan(fit.radius)


@pytest.mark.parametrize("name", CIRCLE_FITS)
def test_collinear_points_fail_without_raising(name: str) -> None:
    x = np.linspace(0, 10, 50)
    fit = CIRCLE_FITS[name](np.column_stack([x, 2 * x + 1]))
    assert not fit or fit.radius > 1e6  # a line is a circle of infinite radius


@pytest.mark.parametrize("name", CIRCLE_FITS)
def test_nan_points_fail_without_raising(name: str) -> None:
    pts, _ = arc_points(5.0, 90, 50)
    pts[3, 0] = np.nan
    fit = CIRCLE_FITS[name](pts)
    assert not fit and "NaN" in fit.reason


@settings(max_examples=60, deadline=None)
@given(
    radius=st.floats(1.0, 100.0),
    cx=st.floats(-500, 500), cy=st.floats(-500, 500),
    arc=st.floats(30.0, 330.0), start=st.floats(0, 2 * math.pi), n=st.integers(12, 200),
)
def test_geometric_and_hyper_recover_any_exact_circle(radius, cx, cy, arc, start, n) -> None:
    t = start + np.linspace(0, math.radians(arc), n)
    pts = np.array([cx, cy]) + radius * np.column_stack([np.cos(t), np.sin(t)])
    for fit in (F.fit_hyper(pts), F.fit_geometric(pts)):
        assert fit
        assert fit.radius == pytest.approx(radius, rel=1e-6)


def ellipse_points(a: float, b: float, angle_deg: float, center: tuple[float, float],
                   arc_deg: float, n: int, sigma: float = 0.0, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = np.linspace(0, math.radians(arc_deg), n) + 0.3
    th = math.radians(angle_deg)
    rot = np.array([[math.cos(th), -math.sin(th)], [math.sin(th), math.cos(th)]])
    pts = np.column_stack([a * np.cos(t), b * np.sin(t)]) @ rot.T + np.array(center)
    return pts + rng.normal(0, sigma, pts.shape)


@pytest.mark.parametrize("arc", [60, 90, 120, 360])
def test_ellipse_fit_recovers_exact_axes(arc: float) -> None:
    # A plane at 35 degrees to the cross-section cuts a 30 mm shaft in this ellipse.
    a, b = 15.0 / math.cos(math.radians(35)), 15.0
    pts = ellipse_points(a, b, 12.0, (4.0, -7.0), arc, 300)
    fit = F.fit_ellipse(pts)
    assert fit
    assert fit.minor_diameter == pytest.approx(30.0, rel=1e-8)
    assert fit.semi_axes[0] == pytest.approx(a, rel=1e-8)
    assert np.allclose(fit.center, [4.0, -7.0], atol=1e-6)
    assert fit.rms < 1e-9


def test_ellipse_fit_with_noise_is_far_worse_than_circle_fits_on_short_arcs() -> None:
    """The paper's Appendix B in numbers: the conic fit is ill-conditioned on a short arc."""
    a, b = 15.0 / math.cos(math.radians(35)), 15.0
    errs = []
    for seed in range(20):
        fit = F.fit_ellipse(ellipse_points(a, b, 0.0, (0, 0), 110, 300, 0.005, seed))
        errs.append(abs(fit.minor_diameter - 30.0) if fit else np.inf)
    assert np.median(errs) > 0.01  # tens of micrometres, against ~3 um for a circle fit


def test_ellipse_of_a_line_is_refused() -> None:
    x = np.linspace(0, 1, 30)
    fit = F.fit_ellipse(np.column_stack([x, x]))
    assert not fit and fit.reason


def test_conic_semi_axes_of_a_circle() -> None:
    centre, major, minor = F.conic_semi_axes(np.array([0.0, 1.0, -2.0, 4.0, 1.0]))
    # x^2 + y^2 - 2x + 4y + 1 = 0 -> (x-1)^2 + (y+2)^2 = 4
    assert np.allclose(centre, [1.0, -2.0])
    assert major == pytest.approx(2.0) and minor == pytest.approx(2.0)


def test_arc_span_and_order_across_the_wrap() -> None:
    t = np.radians(np.array([170.0, -170.0, 150.0, -150.0, 180.0]))
    pts = np.column_stack([np.cos(t), np.sin(t)])
    assert F.arc_span_deg(pts, np.zeros(2)) == pytest.approx(60.0)
    order = F.order_along_arc(pts, np.zeros(2))
    ang = np.degrees(np.unwrap(np.arctan2(pts[order, 1], pts[order, 0])))
    assert np.all(np.diff(ang) > 0) and ang[-1] - ang[0] == pytest.approx(60.0)


@pytest.mark.parametrize("prior", [None, 0.001])
def test_a_fit_without_uncertainty_gets_the_same_one_afterwards(prior: float | None) -> None:
    """A fit that only starts another skips its covariance; when the other fails, the first
    gets it afterwards, the same as had it been computed at once."""
    pts, c = arc_points(20.0, 70, 300, sigma=0.003, seed=4)
    pts[::37] += 0.05  # a few outliers, so that the rejection's clip counts
    w = np.random.default_rng(5).uniform(0.3, 1.0, len(pts))
    if prior is None:
        full = F.fit_geometric(pts, weights=w)
        bare = F.fit_geometric(pts, weights=w, uncertainty=False)
    else:
        full = F.fit_axis_prior(pts, c, prior, weights=w)
        bare = F.fit_axis_prior(pts, c, prior, weights=w, uncertainty=False)
    assert math.isnan(bare.radius_std) and bare.radius == full.radius
    assert np.array_equal(bare.inliers, full.inliers) and not full.inliers.all()
    later = F.with_radius_std(bare, pts, w, prior)
    assert later.radius_std == pytest.approx(full.radius_std, rel=1e-12)
    assert full.radius_std > 0
