"""The reflection model (``service.measure.reflection``) against analytic truth: an arc of a
Gaussian line with a shifted, blurred, fainter copy, seeded noise; where the centres belong is
known exactly."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from service.measure import reflection as rf
from service.measure.stripe import StripeParams, extract_stripe

CENTRE = np.array([-260.0, 150.0])  # px: the arc's centre, off the image to its left
RADIUS = 400.0  # px
SIGMA = 1.1  # px, the stripe's own Gaussian sigma


def arc_image(offset: tuple[float, float] | None, gain: float = 0.3, blur: float = 1.5,
              noise: float = 1.5, seed: int = 0) -> np.ndarray:
    """A 300x240 image (10 DN background) with an arc of radius 400 px, 150 DN high, and a
    reflection: the same arc times ``gain``, blurred by ``blur`` and moved by ``offset``."""
    yy, xx = np.mgrid[0:300, 0:240].astype(np.float64)

    def arc(shift: tuple[float, float], height: float, sigma: float) -> np.ndarray:
        r = np.hypot(xx - CENTRE[0] - shift[0], yy - CENTRE[1] - shift[1])
        return height * np.exp(-0.5 * ((r - RADIUS) / sigma) ** 2)

    img = 10.0 + arc((0.0, 0.0), 150.0, SIGMA)
    if offset is not None:
        wide = math.hypot(SIGMA, blur)
        img += arc(offset, gain * 150.0 * SIGMA / wide, wide)  # blur spreads, keeps the light
    img += np.random.default_rng(seed).normal(0.0, noise, img.shape)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def centres(img: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Steger's centres of the arc away from the image's edges."""
    s = extract_stripe(img, StripeParams(curvature_correction=False))
    keep = (s.xy[:, 1] > 20) & (s.xy[:, 1] < 280)
    return s.xy[keep], s.normal[keep], float(np.median(s.width_px[keep]))


def radial_error(xy: np.ndarray) -> np.ndarray:
    """How far each point lies off the true arc, px (signed, outward positive)."""
    return np.hypot(*(xy - CENTRE).T) - RADIUS


@pytest.mark.parametrize("offset", [(3.0, 0.0), (-3.0, 0.0), (1.5, 0.0), (2.5, 2.5),
                                    (0.5, -4.0), (5.0, 1.0), (0.0, 6.0)])
def test_a_reflection_is_found_and_its_pull_taken_out(offset) -> None:
    xy, n, width = centres(arc_image(offset))
    pulled = np.abs(radial_error(xy)).max()
    found = rf.fit_reflection(arc_image(offset), xy, n, width)
    assert found, found.reason
    assert np.hypot(found.offset_px[0] - offset[0], found.offset_px[1] - offset[1]) < 0.6, \
        found.offset_px
    assert 0.12 < found.gain < 0.3 and found.explained > 0.9, (found.gain, found.explained)
    after = radial_error(xy + found.shift_px[:, None] * n)
    assert pulled > 0.1, pulled  # the reflection did pull the centres (0.12-0.22 px) ...
    assert np.abs(after).max() < 0.04 and abs(after.mean()) < 0.01, after  # ... back
    assert found.describe().startswith("a reflection at (")


def test_a_stripe_alone_has_no_reflection() -> None:
    xy, n, width = centres(arc_image(None))
    found = rf.fit_reflection(arc_image(None), xy, n, width)
    assert not found and "explains" in found.reason, found.reason
    assert abs(np.mean(radial_error(xy))) < 0.02


def test_a_second_line_as_bright_as_the_stripe_is_not_taken_for_a_reflection() -> None:
    img = arc_image((3.0, 0.0), gain=1.6)
    found = rf.fit_reflection(img, *centres(img))
    assert not found and "which one is the stripe" in found.reason, found.reason


def test_too_few_centres_say_so() -> None:
    xy, n, width = centres(arc_image((3.0, 0.0)))
    found = rf.fit_reflection(arc_image((3.0, 0.0)), xy[:20], n[:20], width)
    assert not found and "too few" in found.reason


def test_the_normals_sign_does_not_matter() -> None:
    img = arc_image((2.0, -2.0))
    xy, n, width = centres(img)
    flip = np.where(np.arange(len(n)) % 3 == 0, -1.0, 1.0)[:, None]
    a = rf.fit_reflection(img, xy, n, width)
    b = rf.fit_reflection(img, xy, n * flip, width)
    assert np.allclose(a.shift_px[:, None] * n, b.shift_px[:, None] * (n * flip), atol=1e-6)


@settings(max_examples=25, deadline=None)
@given(st.floats(-4.0, 4.0), st.floats(-4.0, 4.0), st.floats(0.0, 0.4), st.floats(0.3, 3.0),
       st.floats(-0.5, 0.5), st.floats(0.5, 2.5), st.booleans())
def test_the_models_jacobian_is_its_derivative(dx, dy, gain, blur, u, width, ghost) -> None:
    img = arc_image((3.0, 0.0))
    xy, n, _ = centres(img)
    bins = rf._Bins(img, xy, n, rf.ReflectionParams())
    k = bins.nbar.shape[0]
    per_bin = np.concatenate([np.full(k, 10.0), np.full(k, 120.0), np.full(k, u),
                              np.full(k, width), np.full(k, 0.7)])
    p = np.concatenate([[dx, dy, gain, blur], per_bin]) if ghost else per_bin
    jac = rf._model_and_jacobian(p, bins, ghost)[1].reshape(-1, p.size)
    eps = 1e-6
    num = np.stack([(rf._model(p + eps * e, bins, ghost) - rf._model(p - eps * e, bins, ghost))
                    .ravel() / (2 * eps) for e in np.eye(p.size)], axis=1)
    assert np.allclose(jac, num, atol=1e-5 * max(1.0, np.abs(num).max()))


def test_the_profiles_are_sampled_symmetrically_about_each_centre() -> None:
    """The odd (one side against the other) misfit mirrors the samples: a reach that is not
    a whole number of steps must not shift the grid."""
    img = arc_image((3.0, 0.0))
    xy, n, _ = centres(img)
    for reach in (9.0, 9.3, 7.7):
        s = rf._Bins(img, xy, n, rf.ReflectionParams(reach_px=reach)).s
        assert np.allclose(s, -s[::-1]) and 0.0 in s, (reach, s[:3])


def test_profiles_are_sampled_along_the_normals() -> None:
    img = np.zeros((20, 20), np.float32)
    img[:, 12] = 100.0
    prof = rf.cross_profiles(img, np.array([[10.0, 10.0]]), np.array([[1.0, 0.0]]),
                             np.array([0.0, 1.0, 2.0, 2.5]))
    assert np.allclose(prof, [[0.0, 0.0, 100.0, 50.0]])


def test_an_implausible_width_is_held_to_the_profiles_reach() -> None:
    """The geometric method's points may include a lit machine edge (a wide "line"): the fit
    starts within the profiles' reach instead of failing."""
    img = arc_image((3.0, 0.0))
    xy, n, _ = centres(img)
    assert rf.fit_reflection(img, xy, n, 9.4)


def clipped(img: np.ndarray, exposure: float) -> np.ndarray:
    """``img`` over-exposed by ``exposure`` above its 10 DN background, clipped at 255."""
    return np.clip((img.astype(np.float64) - 10.0) * exposure + 10.0, 0, 255).astype(np.uint8)


def test_a_clipped_stripe_is_not_modelled() -> None:
    """A flat-topped stripe is not a Gaussian line: the model, fitted anyway, moved the
    centres of this one past the truth by a quarter of a pixel."""
    img = clipped(arc_image((3.0, 0.0)), 3.6)
    found = rf.fit_reflection(img, *centres(img), lopsided=True)
    assert not found and "clipped" in found.reason, found.reason


def test_a_speckled_stripe_clipped_at_most_centres_is_modelled() -> None:
    """Speckle (contrast 0.25, grain 1.2 px) and three times full scale: 90 % of the centres
    clip, but not the same way, and the mean profiles stay rounded."""
    rng = np.random.default_rng(3)
    grain = cv2.GaussianBlur(rng.standard_normal((300, 240)).astype(np.float32), (0, 0), 1.2)
    light = (arc_image((3.0, 0.0), noise=0.0) - 10.0) * (1.0 + 0.25 * grain / grain.std())
    img = np.clip(3.0 * light + 10.0 + rng.normal(0.0, 1.5, light.shape), 0, 255)
    img = img.astype(np.uint8)
    xy, n, width = centres(img)
    found = rf.fit_reflection(img, xy, n, width, lopsided=True)
    assert found, found.reason
    before, after = radial_error(xy).mean(), radial_error(xy + found.shift_px[:, None] * n)
    assert before > 0.25 and abs(after.mean()) < 0.05, (before, after.mean())


def test_a_stripe_clipped_here_and_there_is_modelled() -> None:
    """Bright grains of speckle clip here and there: one row in eight at twice the light."""
    img = arc_image((3.0, 0.0))
    img[::8] = clipped(img[::8], 2.0)
    xy, n, width = centres(img)
    found = rf.fit_reflection(img, xy, n, width, lopsided=True)
    assert found, found.reason
    # The brighter rows move their own centres by hundredths of a pixel either way; the
    # reflection's pull (0.24 px on average) is taken out.
    before, after = radial_error(xy).mean(), radial_error(xy + found.shift_px[:, None] * n)
    assert before > 0.2 and abs(after.mean()) < 0.15 * before, (before, after.mean())


def test_a_lopsided_stripe_asks_the_asymmetry_to_be_explained() -> None:
    img = arc_image((3.0, 0.0))
    xy, n, width = centres(img)
    strict = rf.ReflectionParams(min_explained=1.0, min_explained_asymmetry=1.0)
    assert "profiles' misfit" in rf.fit_reflection(img, xy, n, width, strict).reason
    assert "profiles' asymmetry" in rf.fit_reflection(img, xy, n, width, strict,
                                                      lopsided=True).reason
    either = rf.ReflectionParams(min_explained=1.0, min_explained_asymmetry=0.9)
    assert not rf.fit_reflection(img, xy, n, width, either)
    assert rf.fit_reflection(img, xy, n, width, either, lopsided=True)


NO_SCREEN = rf.ReflectionParams(screen_margin=10.0)  # the screen never clears: always the fit


def test_the_screen_clears_a_stripe_alone_without_the_fit(monkeypatch) -> None:
    img = arc_image(None)
    xy, n, width = centres(img)
    fits: list[bool] = []
    real = rf._least_squares
    monkeypatch.setattr(rf, "_least_squares",
                        lambda bins, p0, lo, hi, ghost, **kw: fits.append(ghost)
                        or real(bins, p0, lo, hi, ghost, **kw))
    found = rf.fit_reflection(img, xy, n, width)
    assert not found and "at most" in found.reason, found.reason
    assert fits == [False]  # the single line's fit only
    full = rf.fit_reflection(img, xy, n, width, NO_SCREEN)
    assert not full and full.explained < found.explained + 0.02


@pytest.mark.parametrize("gain", [0.05, 0.2, 0.6, 0.9, 1.2])
def test_the_screen_passes_every_reflection_the_fit_would_take_out(gain) -> None:
    """With the screen or without, the same reflections are found, the same pull taken out:
    faint ones (the screen reads within 0.02 of the fit) and bright ones (the single line is
    dragged between the two and fits them badly: the screen stands aside)."""
    for off in ((1.5, 0.0), (2.0, 1.0), (3.0, 0.0), (0.0, 4.0), (-3.0, 3.0), (5.0, 1.0),
                (0.0, 6.0)):
        for blur in (0.8, 1.5, 2.5):
            img = arc_image(off, gain=gain, blur=blur, seed=int(10 * gain + 3 * off[0]) % 97)
            xy, n, width = centres(img)
            screened = rf.fit_reflection(img, xy, n, width)
            full = rf.fit_reflection(img, xy, n, width, NO_SCREEN)
            assert bool(screened) == bool(full), (off, blur, screened.reason, full.reason)
            if full:
                assert np.allclose(screened.shift_px, full.shift_px)


def test_the_fit_reaches_the_minimum_scipy_finds() -> None:
    """The small Levenberg-Marquardt against scipy's trust-region solver on the same model,
    start and bounds."""
    from scipy.optimize import least_squares

    img = arc_image((2.5, 2.5), gain=0.2)
    xy, n, _ = centres(img)
    bins = rf._Bins(img, xy, n, rf.ReflectionParams())
    k = bins.nbar.shape[0]
    free = np.full(k, np.inf)
    lo = np.concatenate([[-9, -9, 0, 0], -free, np.zeros(k), np.full(k, -2.0),
                         np.full(k, 0.3), -free])
    hi = np.concatenate([[9, 9, 1.5, 5], free, free, np.full(k, 2.0), np.full(k, 6.0), free])
    p0 = np.concatenate([[2.0, 2.0, 0.3, 1.6], np.full(k, 10.0), np.full(k, 120.0),
                         np.zeros(k), np.full(k, 1.3), np.zeros(k)])
    ours = rf._least_squares(bins, p0, lo, hi, ghost=True)

    def residual(p: np.ndarray) -> np.ndarray:
        return ((rf._model(p, bins) - bins.mean) * bins.weight).ravel()

    ref = least_squares(residual, p0, bounds=(lo, hi), x_scale="jac", xtol=1e-12,
                        ftol=1e-12)
    assert ours.success
    assert ours.cost <= ref.cost * (1 + 1e-4), (ours.cost, ref.cost)
    assert np.allclose(ours.x[:2], ref.x[:2], atol=0.02), (ours.x[:4], ref.x[:4])


def test_cross_profiles_read_only_the_box_they_need_and_read_it_as_the_whole_image() -> None:
    """Profiles from the samples' box are those of the whole image, also where the samples
    leave the image (its border replicated) or lie wholly outside it."""
    rng = np.random.default_rng(7)
    img = rng.integers(0, 255, (60, 80)).astype(np.uint8)
    s = np.arange(-9.0, 9.01, 0.5)
    for xy in ([[40.3, 30.7], [42.1, 31.2]], [[1.2, 2.5], [78.6, 58.1]], [[-30.0, 5.0]],
               [[200.0, 300.0]]):
        xy = np.array(xy)
        normal = rng.normal(size=xy.shape)
        normal /= np.linalg.norm(normal, axis=1, keepdims=True)
        mx = (xy[:, 0:1] + s * normal[:, 0:1]).astype(np.float32)
        my = (xy[:, 1:2] + s * normal[:, 1:2]).astype(np.float32)
        whole = cv2.remap(img.astype(np.float32), mx, my, cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_REPLICATE)
        np.testing.assert_array_equal(rf.cross_profiles(img, xy, normal, s), whole)
