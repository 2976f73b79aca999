"""The plain full-frame Steger the core is compared with in ``core_throughput``: OpenCV's
separable Gaussian-derivative filters over the whole frame (after the same local background),
Steger's test at every pixel in numpy, one Newton refinement at the first estimate, and the
same weak-point rejection; nothing else (no band, no tracking, no compiled kernels). It is the
extractor as it stood before issue #14, kept here as the yardstick."""

from __future__ import annotations

import math

import cv2
import numpy as np

from service.measure.band import gaussian_kernels
from service.measure.stripe import StripeParams, StripePoints, reject_weak

_SEARCH = 0.6
_HALF_PIXEL = 0.5 + 1e-3


def _full_background(image: np.ndarray, disc_px: int) -> np.ndarray:
    k = int(disc_px) | 1
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k))
    opened = cv2.morphologyEx(image, cv2.MORPH_OPEN, disc, borderType=cv2.BORDER_REPLICATE)
    smooth = cv2.GaussianBlur(opened, (0, 0), k / 4.0)
    return smooth + np.float32(np.median((image - smooth)[::3, ::3]))


def _steger_step(d: dict[str, np.ndarray]) -> tuple[np.ndarray, ...]:
    """Hessian eigenvalues (low, high), the line normal and Steger's offset ``t`` along it."""
    half_tr = 0.5 * (d["xx"] + d["yy"])
    root = np.hypot(0.5 * (d["xx"] - d["yy"]), d["xy"])
    theta = 0.5 * np.arctan2(2.0 * d["xy"], d["xx"] - d["yy"])  # direction of the high one
    nx, ny = -np.sin(theta), np.cos(theta)                       # ... and of the low one
    lam_lo = half_tr - root
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -(nx * d["x"] + ny * d["y"]) / lam_lo
    return lam_lo, half_tr + root, nx, ny, t


def derivatives_at(image: np.ndarray, x: np.ndarray, y: np.ndarray, sigma: float
                   ) -> dict[str, np.ndarray]:
    """The Gaussian-smoothed image and its derivatives up to second order at float positions.

    Each value is the image convolved with the continuous Gaussian (or its derivative) centred
    at ``(x, y)`` itself, summed over the pixels around it, not interpolated between the
    filtered images' pixels: the smoothed profile of a 1 px stripe changes too fast for that,
    and interpolated derivatives (bilinear or cubic) put Steger's centre up to 0.014 px off,
    depending on where the stripe falls between pixels (pixel locking).

    Parameters
    ----------
    image : ndarray, shape (H, W)
        Grey image (float).
    x, y : ndarray, shape (N,)
        Positions, px; within the image, ``4 sigma + 1`` px from its border (else clamped).
    sigma : float
        Gaussian scale, px.

    Returns
    -------
    dict of ndarray
        ``v, x, y, xx, xy, yy``: value, gradient and Hessian at each position.
    """
    h, w = image.shape
    r = max(1, math.ceil(4.0 * sigma))
    cx = np.clip(np.rint(x).astype(np.intp), r, w - 1 - r)
    cy = np.clip(np.rint(y).astype(np.intp), r, h - 1 - r)
    k = np.arange(-r, r + 1)
    patch = image[(cy[:, None] + k)[:, :, None], (cx[:, None] + k)[:, None, :]]

    def kernels(d: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        u = (k[None, :] - d[:, None]) / sigma          # sample position relative to the point
        g = np.exp(-0.5 * u * u) / (math.sqrt(2 * math.pi) * sigma)
        return g, u / sigma * g, (u * u - 1.0) / sigma**2 * g  # G, dG/dpoint, d2G

    gy, gy1, gy2 = kernels(y - cy)
    # Along x first, the three kernels at once (a batched product), then along y.
    along_x = np.matmul(patch.astype(np.float64), np.stack(kernels(x - cx), axis=-1))
    sx, sx1, sx2 = along_x[..., 0], along_x[..., 1], along_x[..., 2]

    def along_y(ky: np.ndarray, row: np.ndarray) -> np.ndarray:
        return np.einsum("ni,ni->n", ky, row)

    return {"v": along_y(gy, sx), "x": along_y(gy, sx1), "y": along_y(gy1, sx),
            "xx": along_y(gy, sx2), "yy": along_y(gy2, sx), "xy": along_y(gy1, sx1)}


def plain_steger(image: np.ndarray, params: StripeParams) -> StripePoints:
    """Steger's centres over the whole frame with his acceptance test, nothing more."""
    img = image.astype(np.float32)
    background = float(np.median(img))
    noise = float(1.4826 * np.median(np.abs(img - background))) or 1.0
    s = float(params.sigma_px)
    r = max(1, math.ceil(4.0 * s))
    roi = img - _full_background(img, params.background_px) + np.float32(background)
    g, g1, g2 = gaussian_kernels(s)

    def filt(kx: np.ndarray, ky: np.ndarray) -> np.ndarray:
        return cv2.sepFilter2D(roi, cv2.CV_32F, kx, ky, borderType=cv2.BORDER_REPLICATE)

    sel = np.zeros(roi.shape, bool)
    sel[r:-r, r:-r] = True
    iy, ix = np.nonzero(sel)
    images = {"v": filt(g, g), "x": filt(g1, g), "y": filt(g, g1),
              "xx": filt(g2, g), "yy": filt(g, g2), "xy": filt(g1, g1)}
    at_pixels = {k: im[iy, ix].astype(np.float64) for k, im in images.items()}
    lam_lo, lam_hi, nx, ny, t = _steger_step(at_pixels)
    noise_curv = max(noise, 1e-6) * math.sqrt(3.0 / (16.0 * math.pi)) / s**3
    ok = ((lam_lo < 0) & (np.abs(lam_lo) > np.abs(lam_hi))
          & (np.abs(t * nx) <= _SEARCH) & (np.abs(t * ny) <= _SEARCH)
          & (-lam_lo > params.min_strength_sigma * noise_curv))
    iy, ix, nx, ny, t = iy[ok], ix[ok], nx[ok], ny[ok], t[ok]
    at = derivatives_at(roi, ix + t * nx, iy + t * ny, s)
    g_n = nx * at["x"] + ny * at["y"]
    h_nn = nx * nx * at["xx"] + 2 * nx * ny * at["xy"] + ny * ny * at["yy"]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = t - g_n / h_nn
    keep = (np.abs(t * nx) <= _HALF_PIXEL) & (np.abs(t * ny) <= _HALF_PIXEL) & (h_nn < 0)
    ix, iy, nx, ny, t = ix[keep], iy[keep], nx[keep], ny[keep], t[keep]
    rv, strength = at["v"][keep], -h_nn[keep]
    with np.errstate(divide="ignore", invalid="ignore"):
        width = np.sqrt(np.clip((rv - background) / strength - s * s, 0.0, None))
    points = StripePoints(np.column_stack([ix + t * nx, iy + t * ny]),
                          np.column_stack([nx, ny]), strength, width, background, noise,
                          peak=rv - background)
    return reject_weak(points, params)
