"""Laser stripe centres to sub-pixel precision: a cheap coarse band, then Steger's method.

Steger (1998) finds the centre of a bright line along its local normal ``n``, the eigenvector of
the Hessian of the Gaussian-smoothed image with the most negative eigenvalue::

    t = -(n . g) / (n^T H n),   centre = pixel + t n,   accepted when |t nx|, |t ny| <= 0.5

Only pixels inside a band around the stripe, found on a 4x-decimated image, are examined, so the
cost scales with the stripe, not the frame. Each centre carries a *strength* (the curvature
across the line, grey levels / px^2) and a *width* (the stripe's own Gaussian sigma, px), so
that weak or smeared points can be rejected or down-weighted.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from service.measure import steger_kernels as kernels
from service.measure.band import (
    Band,
    coarse_band,
    full_scale,
    gaussian_kernels,
    image_statistics,
    tube_band,
    without_background,
)
from service.measure.robust import median, row_index, rows

__all__ = ["Band", "StripeParams", "StripePoints", "extract_stripe", "full_scale",
           "matched_scale", "reject_weak", "steger_centres", "with_scale"]
# Steger accepts a centre within half a pixel; a line exactly on a pixel boundary would be lost
# to float rounding in both neighbours, so allow a hair more (a duplicate is harmless).
_HALF_PIXEL = 0.5 + 1e-3
# First-step window: wide enough that the pixel nearest a centre is always a candidate.
_SEARCH = 0.6


@dataclass(frozen=True)
class StripeParams:
    """Settings of the stripe extractor.

    Attributes
    ----------
    sigma_px : float
        Gaussian scale of the derivative filters, px. Steger: at least ``w / sqrt(3)`` for a
        stripe of half-width ``w``. The least scale: a wide stripe gets wider filters
        (``scale_per_width``).
    scale_per_width : float
        A stripe wider than these filters suit (a thick light sheet) is found again with
        filters of this many times its width (the median of its centres' Gaussian sigma),
        rounded to a quarter pixel, when that is ``rescale_step_px`` or more above
        ``sigma_px`` (``matched_scale``; the measurement does it, for a stripe that is not
        lopsided: wider filters would merge a second line beside it); 0 never. Under
        speckle, filters narrow against the stripe follow the grains inside its core: at a
        sheet sigma of 0.10 mm (a stripe 1.6 px wide) the diameter scattered 4.1 um from
        frame to frame with 1.5 px filters and 3.2 um with 3 px ones; at the default sheet
        (1.1 px) wider filters changed nothing.
    rescale_step_px : float
        How much wider than ``sigma_px`` the matched filters must be to be used (a stripe
        near the boundary stays at ``sigma_px`` instead of changing scale from frame to
        frame).
    max_sigma_px : float
        Widest filters.
    decimation : int
        Down-sampling factor of the coarse pass.
    min_contrast : float
        Least height of the stripe above its surroundings on the decimated copy (where a thin
        stripe is averaged with its neighbours: a third to a half of its full-resolution
        peak), as a fraction of the image's full scale (255 for 8-bit, 65535 for 16-bit), for
        a frame to hold a stripe at all.
    coarse_fraction : float
        Coarse threshold between background (0) and peak (1).
    band_px : int
        Half-width, in full-resolution px, of the band kept around the coarse stripe.
    min_strength_sigma : float
        A centre's curvature must exceed this many standard deviations of the curvature that
        the image noise alone produces.
    min_relative_strength : float
        ... and this fraction of the 90th percentile of the centres' curvatures (weak tails).
    width_range : tuple of float
        Accepted stripe width relative to the median width of the strongest tenth of the
        centres (smeared or split points, and wide lines that are not the laser, outside).
    link_gap_px : float
        Centres closer than this belong to the same line (Steger's linking).
    min_chain : int
        Shortest line, in centres, that is kept: shorter chains are noise or specks.
    max_chain_density : float
        A chain with more centres than this per pixel of its extent is a patch (a glint's
        blob), not a line (``keep_long_chains``).
    curvature_correction : bool
        Undo the shift of a curved stripe's smoothed ridge toward its centre of curvature
        (``correct_curvature_bias``).
    curvature_window_px : float
        Gaussian half-width along the stripe of the local parabola that measures curvature, px.
    optics_blur_px : float
        Gaussian blur (sigma) of the lens, px: blur bends a curved stripe inward too. 0.7 px
        is typical of a well-focused machine-vision lens; set it from your lens.
    background_px : int
        Diameter of the disc whose morphological opening estimates the local background (light
        on the part around the stripe), which is subtracted before the derivatives: a
        background sloping across the stripe shifts Steger's centre by slope / curvature,
        most where the stripe is weak. 0 subtracts nothing.
    track_px : int
        Half-width of the band around the previous frame's stripe, px: how far the stripe
        may move from one frame to the next and still be found without a full search.
    track_reach_px : float
        How far beyond the previous stripe's ends it is looked for, px.
    track_keep : float
        A frame searched near the previous frame's stripe must give at least this fraction
        of its centres, else the whole frame is searched.
    """

    sigma_px: float = 1.5
    scale_per_width: float = 1.6
    rescale_step_px: float = 0.5
    max_sigma_px: float = 4.0
    decimation: int = 4
    min_contrast: float = 0.04
    coarse_fraction: float = 0.2
    band_px: int = 10
    min_strength_sigma: float = 6.0
    min_relative_strength: float = 0.08
    width_range: tuple[float, float] = (0.4, 2.5)
    link_gap_px: float = 2.0
    min_chain: int = 10
    max_chain_density: float = 3.0
    curvature_correction: bool = True
    curvature_window_px: float = 5.0
    optics_blur_px: float = 0.7
    background_px: int = 11
    track_px: int = 3
    track_reach_px: float = 15.0
    track_keep: float = 0.9


@dataclass(frozen=True)
class StripePoints:
    """Sub-pixel stripe centres of one image.

    Attributes
    ----------
    xy : ndarray, shape (N, 2)
        Centres (x, y) in pixels, OpenCV convention (pixel centres at integers).
    normal : ndarray, shape (N, 2)
        Unit normal of the stripe at each centre.
    strength : ndarray, shape (N,)
        Curvature across the stripe, grey levels per px^2 (larger is stronger).
    width_px : ndarray, shape (N,)
        Estimated Gaussian sigma of the stripe profile, px.
    background : float
        Background grey level of the image.
    noise : float
        Robust standard deviation of the background, grey levels.
    reason : str
        Why there are no points, when there are none.
    peak : ndarray, shape (N,), or None
        Height of the smoothed profile above the background at each centre, grey levels:
        ``peak / strength`` is ``w^2 + s^2``, and sums of both over many points give a width
        that the noise does not inflate.
    chain : ndarray of int, shape (N,), or None
        Which chain of linked centres each belongs to (a label shared by the chain's points),
        once chains are formed (``keep_long_chains``).
    balance : ndarray, shape (N,), or None
        How lopsided each centre's profile is (``steger_kernels.side_balance``): a second
        line beside the stripe, a reflection, pulls the centres toward it.
    filter_px : float
        Scale of the derivative filters that found these centres, px
        (``StripeParams.sigma_px``); ``peak`` and ``strength`` are of the image smoothed at
        this scale.
    """

    xy: np.ndarray
    normal: np.ndarray
    strength: np.ndarray
    width_px: np.ndarray
    background: float = 0.0
    noise: float = 0.0
    reason: str = ""
    peak: np.ndarray | None = None
    chain: np.ndarray | None = None
    balance: np.ndarray | None = None
    filter_px: float = 1.5

    def __len__(self) -> int:
        return int(self.xy.shape[0])

    def __bool__(self) -> bool:
        return len(self) > 0

    def subset(self, keep: np.ndarray) -> StripePoints:
        """The points selected by a boolean mask or index array (these points themselves
        when the mask keeps them all: the arrays are never changed in place)."""
        if keep.dtype == np.bool_ and keep.all():
            return self
        i = row_index(keep)
        return StripePoints(
            rows(self.xy, i), rows(self.normal, i), rows(self.strength, i),
            rows(self.width_px, i), self.background, self.noise, self.reason,
            None if self.peak is None else rows(self.peak, i),
            None if self.chain is None else rows(self.chain, i),
            None if self.balance is None else rows(self.balance, i),
            self.filter_px,
        )

    @classmethod
    def empty(cls, reason: str, background: float = 0.0, noise: float = 0.0) -> StripePoints:
        """No centres, and why."""
        z = np.empty((0,))
        return cls(np.empty((0, 2)), np.empty((0, 2)), z, z, background, noise, reason)


def steger_centres(
    image: np.ndarray, band: Band | None, params: StripeParams,
    background: float = 0.0, noise: float = 0.0,
) -> StripePoints:
    """Steger's sub-pixel line centres inside ``band`` (the whole image when None).

    Parameters
    ----------
    image : ndarray, shape (H, W)
        Grey image.
    band : Band or None
        Pixels to examine.
    params : StripeParams
        Extractor settings.
    background, noise : float
        Background grey level and its noise (grey levels), for strength and width.

    Returns
    -------
    StripePoints
        All accepted centres, unsorted.
    """
    h, w = image.shape
    s = float(params.sigma_px)
    r = max(1, math.ceil(4.0 * s))
    band = band or Band.whole((h, w))
    bh, bw = band.mask.shape
    # The box the filters read: the band's and r px around it, within the image.
    y0, y1 = max(0, band.y0 - r), min(h, band.y0 + bh + r)
    x0, x1 = max(0, band.x0 - r), min(w, band.x0 + bw + r)
    roi = image[y0:y1, x0:x1].astype(np.float32)
    sel = np.zeros(roi.shape, bool)
    sel[band.y0 - y0:band.y0 - y0 + bh, band.x0 - x0:band.x0 - x0 + bw] = band.mask
    # Centres need the full filter support inside the image.
    sel[: max(0, r - y0), :] = False
    sel[:, : max(0, r - x0)] = False
    if y1 > h - r:
        sel[roi.shape[0] - (y1 - (h - r)):, :] = False
    if x1 > w - r:
        sel[:, roi.shape[1] - (x1 - (w - r)):] = False
    spans = _spans_in(band, roi.shape, x0, y0)
    if params.background_px > 0:
        # Only where the filters, the refinement and the side balance read: the band and
        # the filters' radius, a Newton step and a pixel about it (the balance's 5 px too).
        roi = without_background(roi, params.background_px, background, spans,
                                 max(r + 2, 7))
    g, g1, g2 = gaussian_kernels(s)
    iy, ix, derivs = kernels.band_hessian(roi, sel, *spans, g, g1, g2)
    if iy.size == 0:
        return StripePoints.empty("no stripe: band lies on the image border", background, noise)
    noise_curv = max(noise, 1e-6) * math.sqrt(3.0 / (16.0 * math.pi)) / s**3
    ok, nx, ny, t = kernels.steger_test(derivs, params.min_strength_sigma * noise_curv, _SEARCH)
    if ok.size == 0:
        return StripePoints.empty("no stripe: no line centre passed Steger's test", background,
                                  noise)
    # One Newton refinement with the derivatives at the first estimate (evaluated there, not
    # interpolated): a single step from a pixel centre overshoots a Gaussian profile by up
    # to ~0.02 px.
    x, y, nx, ny, strength, width, peak = kernels.refine_centres(
        roi, iy[ok], ix[ok], nx, ny, t, s, background, _HALF_PIXEL)
    # A level cancels (one side less the other): the roi as it is.
    balance = kernels.side_balance(roi, x, y, nx, ny, peak)
    return StripePoints(
        xy=np.column_stack([x + x0, y + y0]), normal=np.column_stack([nx, ny]),
        strength=strength, width_px=width, background=background, noise=noise, peak=peak,
        balance=balance, filter_px=s)


def _spans_in(band: Band, shape: tuple[int, int], x0: int, y0: int
              ) -> tuple[np.ndarray, np.ndarray]:
    """The band's row spans (``Band.row_spans``) in a box of ``shape`` at (x0, y0)."""
    first, last = np.full(shape[0], shape[1], np.int64), np.full(shape[0], -1, np.int64)
    a, b = band.row_spans()
    dy, dx = band.y0 - y0, band.x0 - x0
    some = b >= a
    first[dy:dy + len(a)] = np.where(some, a + dx, shape[1])
    last[dy:dy + len(b)] = np.where(some, b + dx, -1)
    return first, last


def reject_weak(points: StripePoints, params: StripeParams) -> StripePoints:
    """Drop weak (low curvature) and smeared or split (odd width) centres."""
    if not points:
        return points
    lo, hi = params.width_range
    return points.subset(kernels.not_weak(points.strength, points.width_px,
                                          params.min_relative_strength, lo, hi))


def keep_long_chains(points: StripePoints, gap_px: float, min_chain: int,
                     max_density: float = 3.0) -> StripePoints:
    """Link centres closer than ``gap_px`` into lines; keep lines of ``min_chain`` or more
    that are lines, not patches.

    A laser stripe gives about one centre per pixel along its length, so its centres form long
    chains; noise and specks that pass Steger's test give isolated centres or short chains. A
    glint's blob passes Steger's test all over its shoulder (there the Hessian looks like a
    line running outward), so its centres fill a patch: more than ``max_density`` centres per
    pixel of the chain's extent (the diagonal of its box) is a blob, not a line, unless it
    touches a long line (the fat end of a stripe seen at a grazing angle looks the same; a
    glint on the stripe is left to the section's consensus).
    """
    if len(points) == 0:
        return points
    labels = kernels.chain_labels(points.xy, float(gap_px))
    sizes = kernels.chain_sizes(labels)
    keep = sizes >= min_chain
    if keep.any():
        is_patch = kernels.in_patch(points.xy, labels, float(max_density))
        if is_patch.any():
            long_line = (sizes >= 5 * min_chain) & ~is_patch
            is_patch &= keep
            if is_patch.any() and long_line.any():
                # Imported here: scipy.spatial costs 0.35 s of CPU at every start of a process
                # that measures, and only a frame with a patch of light needs it.
                from scipy.spatial import cKDTree

                near, _ = cKDTree(points.xy[long_line]).query(points.xy[is_patch],
                                                              distance_upper_bound=2 * gap_px)
                touching = np.unique(labels[is_patch][np.isfinite(near)])
                is_patch &= ~np.isin(labels, touching)
            keep &= ~is_patch
    return replace(points, chain=labels).subset(keep)


def correct_curvature_bias(points: StripePoints, sigma_px: float, window_px: float = 5.0
                           ) -> StripePoints:
    """Move centres of a curved stripe back out of the curve.

    Smoothing a line that curves with curvature ``kappa`` with a Gaussian of scale ``s`` moves
    its ridge toward the centre of curvature by about ``s^2 kappa / 2`` (in polar form the heat
    equation has a drift term ``u_r / r``; the line's own width does not matter). Near the ends
    of the stripe on a shaft, where its image bends sharply, that is several hundredths of a
    pixel: micrometres that a short-arc fit amplifies tenfold. Here each centre's curvature
    comes from a parabola ``v = a + b u + c u^2`` fitted, with Gaussian weights along the
    stripe, to its neighbours in the frame of its own tangent ``u`` and normal ``v``
    (``kappa = 2c``); the centre then moves by ``-s^2 c`` along
    its normal.

    Parameters
    ----------
    points : StripePoints
        Centres from ``steger_centres``.
    sigma_px : float
        Total smoothing, px: the derivative filters' scale combined with any known lens blur.
    window_px : float
        Gaussian weight half-width along the stripe, px.

    Returns
    -------
    StripePoints
        The same points, moved.
    """
    n_pts = len(points)
    k = min(int(4 * window_px) + 1, n_pts)
    if k < 5:
        return points
    xy, nrm = points.xy, points.normal
    idx = kernels.nearest_neighbours(np.ascontiguousarray(xy), k)
    c = kernels.local_parabolas(xy, nrm, idx, float(window_px))
    shift = -(sigma_px**2) * c
    # A parabola on too few neighbours (an isolated blob) says nothing: leave those points.
    shift[np.abs(shift) > 0.5] = 0.0
    return replace(points, xy=xy + shift[:, None] * nrm)


def extract_stripe(image: np.ndarray, params: StripeParams | None = None,
                   near: np.ndarray | None = None) -> StripePoints:
    """Sub-pixel centres of the laser stripe in a grey image.

    Parameters
    ----------
    image : ndarray, shape (H, W)
        Grey image (uint8, uint16 or float).
    params : StripeParams, optional
        Extractor settings.
    near : ndarray, shape (N, 2), optional
        Where the stripe was in the previous frame (its centres, px): the band is the pixels
        within ``params.track_px`` of them, and the whole frame is searched only when that
        finds fewer than ``params.track_keep`` of their number (the stripe moved or was
        lost).

    Returns
    -------
    StripePoints
        Centres in pixels; empty, with ``reason`` set, when the image holds no stripe.
    """
    params = params or StripeParams()
    if image.ndim != 2:
        return StripePoints.empty(f"expected a grey image, got shape {image.shape}")
    if near is not None and len(near) >= params.min_chain:
        tube = tube_band(near, image.shape, params.track_px, params.track_reach_px)
        if tube is not None:
            points = _centres_in(image, tube, params,
                                 *image_statistics(image, params.decimation))
            if len(points) >= params.track_keep * len(near):
                return points
    band, background, noise, reason = coarse_band(
        image, params.decimation, params.min_contrast, params.coarse_fraction, params.band_px)
    if band is None:
        return StripePoints.empty(reason, background, noise)
    return _centres_in(image, band, params, background, noise)


def matched_scale(width_px: np.ndarray, params: StripeParams) -> float:
    """The derivative filters' scale that suits a stripe of these centres' widths, px
    (``StripeParams.scale_per_width``): ``params.sigma_px`` unless the stripe is wide."""
    if not params.scale_per_width > 0 or len(width_px) == 0:
        return float(params.sigma_px)
    want = params.scale_per_width * median(width_px)
    if not want >= params.sigma_px + params.rescale_step_px:
        return float(params.sigma_px)
    return float(min(round(want * 4.0) / 4.0, params.max_sigma_px))


def with_scale(params: StripeParams, scale_px: float) -> StripeParams:
    """``params`` with derivative filters of ``scale_px`` and a background disc wide enough
    to pass under a stripe they suit (six of its sigmas, ``scale_px / scale_per_width``)."""
    if scale_px == params.sigma_px:
        return params
    disc = params.background_px
    if disc > 0 and params.scale_per_width > 0:
        disc = max(disc, 2 * math.ceil(3.0 * scale_px / params.scale_per_width) + 1)
    return replace(params, sigma_px=float(scale_px), background_px=disc)


def _centres_in(image: np.ndarray, band: Band, params: StripeParams, background: float,
                noise: float) -> StripePoints:
    points = reject_weak(steger_centres(image, band, params, background, noise), params)
    points = keep_long_chains(points, params.link_gap_px, params.min_chain,
                              params.max_chain_density)
    if not points:
        return StripePoints.empty("no stripe: no line of centres long enough", background,
                                  noise)
    if params.curvature_correction:
        smoothing = math.hypot(params.sigma_px, params.optics_blur_px)
        points = correct_curvature_bias(points, smoothing, params.curvature_window_px)
    return points
