"""Where to look for the stripe: a band of pixels around it, found on a decimated copy of the
whole frame (``coarse_band``) or around the previous frame's stripe (``tube_band``), and the
local background under it.

A band is kept as a mask over its own bounding box, so that what follows costs what the stripe
costs, not what the frame costs.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import cv2
import numpy as np

from service.measure import steger_kernels as kernels

_TOPHAT_PX = 5
"""Disc of the coarse pass's top-hat, decimated px (20 full-resolution px at decimation 4):
wider than a stripe, narrower than a machine edge or a light gradient."""


@dataclass(frozen=True)
class Band:
    """Pixels to examine: ``mask`` over the box whose top-left pixel is (``x0``, ``y0``).

    Attributes
    ----------
    mask : ndarray of bool, shape (h, w)
        True inside the band.
    x0, y0 : int
        Image position of ``mask[0, 0]``, px.
    """

    mask: np.ndarray
    x0: int = 0
    y0: int = 0
    spans: tuple[np.ndarray, np.ndarray] | None = None
    """Each row's first and last column in the band (``last < first`` for none), when the
    band's maker knows them (``row_spans`` works them out otherwise)."""

    def row_spans(self) -> tuple[np.ndarray, np.ndarray]:
        """Each row's first and last column in the band, ``last < first`` in rows with none."""
        if self.spans is not None:
            return self.spans
        w = self.mask.shape[1]
        first = np.argmax(self.mask, axis=1)
        last = w - 1 - np.argmax(self.mask[:, ::-1], axis=1)
        empty = ~self.mask[np.arange(len(first)), first]
        first[empty], last[empty] = w, -1
        return first, last

    @classmethod
    def whole(cls, shape: tuple[int, int]) -> Band:
        """Every pixel of an image of ``shape`` (h, w)."""
        h, w = shape
        return cls(np.ones(shape, bool), spans=(np.zeros(h, np.int64), np.full(h, w - 1)))

    @classmethod
    def from_mask(cls, mask: np.ndarray) -> Band | None:
        """The band of a full-image mask, cropped to its bounding box (None when empty)."""
        rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
        if rows.size == 0:
            return None
        y0, y1, x0, x1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
        return cls(mask[y0:y1, x0:x1], int(x0), int(y0))


def full_scale(image: np.ndarray) -> float:
    """Largest grey level the image's dtype can hold (1.0 for float images)."""
    if np.issubdtype(image.dtype, np.integer):
        return float(np.iinfo(image.dtype).max)
    return 1.0


def image_statistics(image: np.ndarray, decimation: int, spacing: int = 8
                     ) -> tuple[float, float]:
    """The image's background grey level and noise, from the means of ``decimation``-square
    blocks, one block in ``spacing`` each way.

    Returns
    -------
    background : float
        Median of the block means, grey levels.
    noise : float
        Robust standard deviation of the darker three quarters of the block means, scaled
        back to single pixels (times ``decimation``), grey levels.
    """
    h, w = image.shape
    k = max(1, int(decimation))
    if h < k or w < k:
        return float(np.median(image)), 0.0
    background, noise = kernels.background_and_noise(image, k, spacing)
    return float(background), float(noise)


def coarse_band(image: np.ndarray, decimation: int, min_contrast: float,
                coarse_fraction: float, band_px: int
                ) -> tuple[Band | None, float, float, str]:
    """Find a band around the stripe on a decimated copy of the image.

    Parameters
    ----------
    image : ndarray, shape (H, W)
        Grey image, any numeric dtype.
    decimation : int
        Down-sampling factor.
    min_contrast : float
        Least stripe peak above background, as a fraction of the dtype's full scale.
    coarse_fraction : float
        Threshold between background (0) and peak (1).
    band_px : int
        Half-width of the band, full-resolution px.

    Returns
    -------
    band : Band or None
        None when the image holds no stripe.
    background : float
        Median grey level.
    noise : float
        Robust standard deviation of the background's grey levels.
    reason : str
        Why there is no band, when ``band`` is None.
    """
    h, w = image.shape
    k = max(1, int(decimation))
    small = cv2.resize(image.astype(np.float32), (max(1, w // k), max(1, h // k)),
                       interpolation=cv2.INTER_AREA)
    background, noise = image_statistics(image, k)
    # What stands out of its surroundings as a thin structure: the white top-hat (the image
    # less its opening by a disc wider than a stripe) leaves out light gradients, bright
    # machine parts and anything else wider than the disc.
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (_TOPHAT_PX, _TOPHAT_PX))
    small = cv2.morphologyEx(small, cv2.MORPH_TOPHAT, disc, borderType=cv2.BORDER_REPLICATE)
    peak = float(cv2.GaussianBlur(small, (3, 3), 0).max())
    if peak < min_contrast * full_scale(image):
        return None, background, noise, (
            f"no stripe: the brightest thin structure stands only {peak:.1f} grey levels above"
            f" its surroundings (need {min_contrast * full_scale(image):.1f})"
        )
    # The stripe's level: the median of what clearly stands out (a few glints, however
    # bright, are fewer pixels than the stripe and do not raise it).
    floor = 4.0 * noise / k
    standing = small[small > max(floor, 0.5 * min_contrast * full_scale(image))]
    level = float(np.median(standing)) if standing.size else peak
    threshold = max(coarse_fraction * level, floor)
    mask = (small > threshold).astype(np.uint8)
    _, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    # Drop specks (hot pixels, glints) of a few decimated pixels.
    big = np.flatnonzero(stats[1:, cv2.CC_STAT_AREA] >= 3) + 1
    if big.size == 0:
        return None, background, noise, "no stripe: no bright structure larger than a speck"
    mask = np.isin(labels, big).astype(np.uint8)
    radius = max(1, math.ceil(band_px / k))
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
    mask = cv2.dilate(mask, kernel)
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    sy0, sy1, sx0, sx1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
    # Back to full resolution, the box only (as resizing the whole mask would give it).
    y0, x0 = sy0 * h // mask.shape[0], sx0 * w // mask.shape[1]
    y1, x1 = min(h, -(-sy1 * h // mask.shape[0])), min(w, -(-sx1 * w // mask.shape[1]))
    ys = np.minimum(np.arange(y0, y1) * mask.shape[0] // h, mask.shape[0] - 1)
    xs = np.minimum(np.arange(x0, x1) * mask.shape[1] // w, mask.shape[1] - 1)
    band = mask[ys[:, None], xs[None, :]].astype(bool)
    return Band(band, int(x0), int(y0)), background, noise, ""


def extend_ends(xy: np.ndarray, length_px: float, span: int = 15) -> np.ndarray:
    """The points and, beyond each end of the line they form, points every pixel for
    ``length_px`` along its direction there (the ends are the extremes along the points'
    principal direction; the direction is from the ``span`` points nearest each end;
    compiled: ``steger_kernels.end_extensions``)."""
    pts = np.ascontiguousarray(xy, np.float64)
    return np.concatenate([pts, kernels.end_extensions(pts, int(length_px), int(span))])


def tube_band(near_xy: np.ndarray, shape: tuple[int, int], radius_px: int,
              reach_px: float = 0.0) -> Band | None:
    """The pixels within ``radius_px`` of any of ``near_xy`` (px; the previous frame's stripe
    centres), the line they form extended by ``reach_px`` beyond both ends (a stripe's ends
    come and go with the speckle), inside an image of ``shape`` (h, w); None when none lies
    in the image."""
    h, w = shape
    pts = np.rint(extend_ends(near_xy, reach_px)).astype(np.int64)
    inside = (pts[:, 0] >= 0) & (pts[:, 0] < w) & (pts[:, 1] >= 0) & (pts[:, 1] < h)
    pts = pts[inside]
    if len(pts) == 0:
        return None
    x0 = max(0, int(pts[:, 0].min()) - radius_px)
    y0 = max(0, int(pts[:, 1].min()) - radius_px)
    x1 = min(w, int(pts[:, 0].max()) + radius_px + 1)
    y1 = min(h, int(pts[:, 1].max()) + radius_px + 1)
    mask, first, last = kernels.disc_mask(y1 - y0, x1 - x0, pts[:, 1] - y0, pts[:, 0] - x0,
                                          int(radius_px))
    return Band(mask, x0, y0, (first, last))


@functools.lru_cache(maxsize=32)
def gaussian_kernels(sigma: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sampled Gaussian and its first two derivatives, normalised on the sampled support
    (kept per scale, read-only: every frame asks for the same few)."""
    r = max(1, math.ceil(4.0 * sigma))
    x = np.arange(-r, r + 1, dtype=np.float64)
    g = np.exp(-0.5 * (x / sigma) ** 2)
    g /= g.sum()
    g1 = x / sigma**2 * g             # cv2 filters correlate: +x, not the textbook -x
    g1 /= (x * g1).sum()             # unit response to a unit ramp
    g2 = (x**2 / sigma**4 - 1.0 / sigma**2) * g
    g2 -= g2.mean()                  # zero response to a constant
    g2 /= 0.5 * (x**2 * g2).sum()    # response 2 to x^2 (second derivative of x^2)
    out = g.astype(np.float32), g1.astype(np.float32), g2.astype(np.float32)
    for a in out:
        a.flags.writeable = False
    return out


def without_background(image: np.ndarray, disc_px: int, level: float,
                       need: tuple[np.ndarray, np.ndarray] | None = None, pad_px: int = 0
                       ) -> np.ndarray:
    """``image`` (float32) less a smooth estimate of what lies under a thin bright line, plus
    ``level`` (the image's background grey level); with ``need`` (each row's first and last
    column needed, as ``Band.row_spans``) only within ``pad_px`` of those, in ``image``
    itself (float32; its other pixels keep their values).

    The estimate: the morphological opening by a disc wider than the line (it removes the
    line, keeps slower shading), then a Gaussian to take the opening's corners off, raised to
    the image's median level about it. Computed at half resolution (a 2x2 mean, the Gaussian
    halved, the disc a little over half) and brought back by bilinear interpolation, fused
    with the subtraction (``steger_kernels.subtract_upsampled``): the background changes
    slowly by construction, and this costs a quarter of the full-resolution opening (measured
    on a tracked stripe's box: 0.3 against 1.0 ms; the two differ by 0.4 grey levels RMS
    under the stripe).
    """
    h, w = image.shape
    if h < 4 or w < 4:
        return image - np.float32(np.median(image)) + np.float32(level)
    # An even box: OpenCV's exact halving is ten times faster than its fractional one.
    h2, w2 = h // 2, w // 2
    small = cv2.resize(image[:2 * h2, :2 * w2], (w2, h2), interpolation=cv2.INTER_AREA)
    # The 2x2 mean spreads a line over one more half-resolution pixel: a disc of half the
    # size lets its wings through (widths of a 1.6 px line came out 0.17 px^2 too small).
    k = (int(disc_px) // 2 + 2) | 1
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k))
    opened = cv2.morphologyEx(small, cv2.MORPH_OPEN, disc, borderType=cv2.BORDER_REPLICATE)
    smooth = cv2.GaussianBlur(opened, (0, 0), max(int(disc_px), 1) / 8.0)
    # The opening of a noisy image lies below it by a good part of the noise (a minimum
    # filter comes first), which would add to every stripe height: the median difference,
    # which a thin stripe does not move, is put back (sampled: it is only a level).
    first, last = (np.zeros(0, np.int64),) * 2 if need is None else need
    return kernels.subtract_upsampled(image, smooth, float(level), 6, 2 * h2, 2 * w2, first,
                                      last, int(pad_px))
