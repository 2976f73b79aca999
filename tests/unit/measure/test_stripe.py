"""Steger centres against analytic truth: rendered lines of known sub-pixel position."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from service.measure.geometry import geometry_of
from service.measure.stripe import (
    StripeParams,
    extract_stripe,
    matched_scale,
    steger_centres,
    with_scale,
)


def line_image(angle_deg: float, offset_px: float, width_px: float = 1.6, amp: float = 150.0,
               size: tuple[int, int] = (200, 160), noise: float = 0.0, seed: int = 0,
               dtype: type = np.uint8) -> tuple[np.ndarray, np.ndarray, float]:
    """A straight Gaussian line through the image centre shifted by ``offset_px`` along its
    normal. Returns the image, the unit normal and the line's offset c in n . p = c."""
    w, h = size
    th = math.radians(angle_deg)
    n = np.array([math.cos(th), math.sin(th)])
    centre = np.array([(w - 1) / 2.0, (h - 1) / 2.0])
    c = float(n @ centre + offset_px)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    dist = n[0] * xx + n[1] * yy - c
    img = 5.0 + amp * np.exp(-0.5 * (dist / width_px) ** 2)
    if noise:
        img += np.random.default_rng(seed).normal(0, noise, img.shape)
    scale = 257.0 if dtype == np.uint16 else 1.0
    return np.clip(np.rint(img * scale), 0, np.iinfo(dtype).max).astype(dtype), n, c


def centre_errors(points: np.ndarray, n: np.ndarray, c: float, size: tuple[int, int],
                  margin: int = 12) -> np.ndarray:
    w, h = size
    inside = ((points[:, 0] > margin) & (points[:, 0] < w - margin)
              & (points[:, 1] > margin) & (points[:, 1] < h - margin))
    return points[inside] @ n - c


@pytest.mark.parametrize("angle", [0.0, 17.0, 45.0, 62.5, 90.0, 133.0])
@pytest.mark.parametrize("offset", [0.0, 0.27, -0.41])
def test_noise_free_line_centre_within_0_02_px(angle: float, offset: float) -> None:
    img, n, c = line_image(angle, offset)
    pts = extract_stripe(img)
    err = centre_errors(pts.xy, n, c, (200, 160))
    assert err.size > 100  # one centre per pixel step along the line
    # 8-bit quantisation alone leaves a few thousandths of a pixel.
    assert np.max(np.abs(err)) < 0.02, np.max(np.abs(err))


def test_noisy_line_centre_error_is_small_and_unbiased() -> None:
    errs = []
    for seed in range(5):
        img, n, c = line_image(30.0, 0.33, noise=4.0, seed=seed)
        errs.append(centre_errors(extract_stripe(img).xy, n, c, (200, 160)))
    err = np.concatenate(errs)
    # Measured: std about 0.03 px at SNR 150/4, bias well below that.
    assert np.std(err) < 0.06
    assert abs(np.mean(err)) < 0.01


def test_sixteen_bit_images_give_the_same_centres() -> None:
    img8, n, c = line_image(40.0, 0.2)
    img16, *_ = line_image(40.0, 0.2, dtype=np.uint16)
    e8 = centre_errors(extract_stripe(img8).xy, n, c, (200, 160))
    e16 = centre_errors(extract_stripe(img16).xy, n, c, (200, 160))
    assert np.max(np.abs(e16)) < 0.01
    assert np.max(np.abs(e8)) < 0.02


def test_width_and_strength_are_reported() -> None:
    img, *_ = line_image(10.0, 0.0, width_px=1.6)
    pts = extract_stripe(img)
    assert np.median(pts.width_px) == pytest.approx(1.6, rel=0.15)
    assert (pts.strength > 0).all()
    assert np.allclose(np.linalg.norm(pts.normal, axis=1), 1.0)


@pytest.mark.parametrize("angle", [0.0, 90.0, 8.0])
def test_no_pixel_locking_of_a_thin_line(angle: float) -> None:
    """A 1.15 px line (the simulated rig's stripe) along the pixel grid, at sub-pixel offsets:
    with the derivatives interpolated between pixels the centre was up to 0.014 px off
    (about 1 um at the shaft), the same all along the line wherever it runs with the grid."""
    worst = 0.0
    th = math.radians(angle)
    n = np.array([math.cos(th), math.sin(th)])
    yy, xx = np.mgrid[0:160, 0:200].astype(np.float64)
    for offset in np.linspace(0.0, 1.0, 10, endpoint=False):
        c = float(n @ np.array([99.5, 79.5]) + offset)
        img = (0.02 + 0.6 * np.exp(-0.5 * ((n[0] * xx + n[1] * yy - c) / 1.15) ** 2))
        pts = extract_stripe(img.astype(np.float32), StripeParams(curvature_correction=False))
        worst = max(worst, abs(float(np.median(centre_errors(pts.xy, n, c, (200, 160))))))
    assert worst < 0.003, worst


@pytest.mark.parametrize("width", [0.8, 1.0, 1.6])
def test_widths_are_unbiased_at_every_position_and_angle(width: float) -> None:
    """The width comes from the smoothed profile's height over its curvature at the centre;
    interpolated there bilinearly from the filtered images it was about 0.18 px^2 too large in
    variance (0.09 px on a 1 px line); evaluated at the centre it is exact but for 8 bits."""
    excess = []
    for angle, offset in [(a, o) for a in (0.0, 23.0, 45.0, 71.0, 120.0)
                          for o in (0.0, 0.25, 0.5, -0.3)]:
        img, *_ = line_image(angle, offset, width_px=width)
        pts = extract_stripe(img)
        excess.append(float(np.median(pts.width_px**2)) - width**2)
    assert abs(np.mean(excess)) < 0.05, excess
    assert np.max(np.abs(excess)) < 0.08, excess


def test_height_over_curvature_summed_is_not_inflated_by_noise() -> None:
    """Per point, noise in the curvature inflates height / curvature (the mean of 1/x exceeds
    1/mean); the ratio of sums over the line is what ``sheet_sigma_from_profile`` uses."""
    img, *_ = line_image(30.0, 0.2, width_px=1.0, noise=6.0, seed=3)
    pts = extract_stripe(img)
    s = StripeParams().sigma_px
    summed = pts.peak.sum() / pts.strength.sum() - s * s
    assert summed == pytest.approx(1.0, abs=0.08)


def test_rendered_shaft_stripe_lies_on_the_projected_section(renderer) -> None:
    """Centres of a clean rendered stripe lie on the exact image of the plane-cylinder curve."""
    geo = geometry_of(renderer.calibration)
    d = 30.0
    img = renderer.render_clean(d)
    pts = extract_stripe(img * 1.0, StripeParams()).xy
    assert len(pts) > 200
    # Exact curve: dense points of the plane/cylinder intersection, projected with distortion.
    from service.measure.section import orthonormal_basis

    e1, e2 = orthonormal_basis(geo.axis_direction)
    t = np.linspace(0, 2 * np.pi, 200000)
    ring = geo.axis_point + (d / 2) * (np.cos(t)[:, None] * e1 + np.sin(t)[:, None] * e2)
    k = (geo.plane_d - ring @ geo.plane_normal) / (geo.axis_direction @ geo.plane_normal)
    curve3 = ring + k[:, None] * geo.axis_direction
    curve, _ = cv2.projectPoints(curve3, np.zeros(3), np.zeros(3), geo.camera_matrix,
                                 geo.dist_coeffs)
    curve = curve.reshape(-1, 2)
    from scipy.spatial import cKDTree

    dist, _ = cKDTree(curve).query(pts)
    # The exact curve is sampled every ~0.01 px; centres are within a few hundredths.
    assert np.median(dist) < 0.03, np.median(dist)
    assert np.percentile(dist, 95) < 0.1, np.percentile(dist, 95)


def test_blank_frame_has_no_stripe_and_says_why() -> None:
    rng = np.random.default_rng(3)
    img = np.clip(rng.normal(8, 2, (300, 400)), 0, 255).astype(np.uint8)
    pts = extract_stripe(img)
    assert not pts
    assert "no stripe" in pts.reason


def test_saturated_flat_frame_has_no_stripe() -> None:
    img = np.full((300, 400), 255, np.uint8)
    assert not extract_stripe(img)


def test_colour_image_is_refused_with_reason() -> None:
    pts = extract_stripe(np.zeros((10, 10, 3), np.uint8))
    assert not pts and "grey" in pts.reason


def test_steger_on_whole_image_without_band() -> None:
    img, n, c = line_image(75.0, 0.1)
    pts = steger_centres(img, None, StripeParams(), background=5.0, noise=1.0)
    err = centre_errors(pts.xy, n, c, (200, 160))
    assert np.max(np.abs(err)) < 0.02


def ring_image(radius_px: float, width_px: float = 1.5, size: int = 160) -> np.ndarray:
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float64)
    c = (size - 1) / 2.0 + 0.3
    r = np.hypot(xx - c, yy - c)
    return 5.0 + 150.0 * np.exp(-0.5 * ((r - radius_px) / width_px) ** 2), c


@pytest.mark.parametrize("radius", [25.0, 40.0, 60.0])
def test_curvature_correction_removes_the_inward_shift_of_a_curved_stripe(radius: float) -> None:
    img, c = ring_image(radius)
    plain = extract_stripe(img, StripeParams(curvature_correction=False))
    fixed = extract_stripe(img, StripeParams(optics_blur_px=0.0)).xy  # no lens in this image
    r_plain = np.hypot(*(plain.xy - c).T) - radius
    r_fixed = np.hypot(*(fixed - c).T) - radius
    # Theory: smoothing by s moves the ridge inward by about s^2 / (2 radius).
    expected = plain.filter_px**2 / (2 * radius)
    assert np.mean(r_plain) == pytest.approx(-expected, rel=0.15)
    assert abs(np.mean(r_fixed)) < 0.15 * expected


@pytest.mark.parametrize("width, scale", [(1.0, 1.5), (1.25, 1.5), (1.6, 2.5), (2.2, 3.5),
                                          (3.0, 4.0)])
def test_a_wide_stripe_gets_filters_that_suit_it(width: float, scale: float) -> None:
    """1.6 times the stripe's width, to a quarter pixel, when that is half a pixel or more
    above the least scale (a stripe near the boundary keeps it), at most 4 px."""
    img, *_ = line_image(30.0, 0.2, width_px=width, noise=1.0)
    points = extract_stripe(img)
    assert points.filter_px == 1.5
    assert matched_scale(points.width_px, StripeParams()) == scale
    assert matched_scale(points.width_px, StripeParams(scale_per_width=0.0)) == 1.5


def test_wider_filters_come_with_a_background_disc_that_passes_under_the_stripe() -> None:
    params = with_scale(StripeParams(), 3.5)
    assert params.sigma_px == 3.5 and params.background_px >= 6 * 3.5 / 1.6
    assert with_scale(StripeParams(), 1.5) == StripeParams()
    assert with_scale(StripeParams(background_px=0), 3.5).background_px == 0


def test_a_wide_stripe_found_with_filters_that_suit_it_is_found_where_it_is() -> None:
    """Steger's centre of a Gaussian line is exact at any scale: the wider filters move no
    centre of a straight line (8 bits aside)."""
    img, n, c = line_image(23.0, 0.3, width_px=2.2)
    wide = extract_stripe(img, with_scale(StripeParams(), 3.5))
    assert wide.filter_px == 3.5 and len(wide) > 150
    err = centre_errors(wide.xy, n, c, (200, 160), margin=20)
    assert np.max(np.abs(err)) < 0.02
