"""The plain full-frame Steger the core is compared with in ``core_throughput``, as fast as a
plain Steger can be: OpenCV's separable Gaussian-derivative filters in float32 over the whole
frame, then at every pixel the Hessian's eigenvalues, its eigenvector (in closed form, no
trigonometry) and Steger's test, vectorised in numpy in float32; nothing else (no band, no
tracking, no background model, no compiled kernels, no refinement).

``plain_steger_pruned`` is the same with one step that is not plain Steger: the eigenvector
and the sub-pixel offset only where the curvature already passes the strength test. The core
bench reports both ratios.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from service.measure.band import gaussian_kernels
from service.measure.stripe import StripeParams, StripePoints, reject_weak

_HALF_PIXEL = np.float32(0.5 + 1e-3)


def _filters(image: np.ndarray, sigma: float) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    img = np.asarray(image, np.float32)
    g, g1, g2 = gaussian_kernels(sigma)

    def filt(kx: np.ndarray, ky: np.ndarray) -> np.ndarray:
        return cv2.sepFilter2D(img, cv2.CV_32F, kx, ky, borderType=cv2.BORDER_REPLICATE)

    return img, {"v": filt(g, g), "x": filt(g1, g), "y": filt(g, g1), "xx": filt(g2, g),
                 "yy": filt(g, g2), "xy": filt(g1, g1)}


def _statistics(img: np.ndarray) -> tuple[float, float]:
    sub = img[::4, ::4]
    background = float(np.median(sub))
    return background, float(1.4826 * np.median(np.abs(sub - background))) or 1.0


def _normal(a: np.ndarray, b: np.ndarray, c: np.ndarray, lam: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray]:
    """Unit eigenvector of [[a, b], [b, c]] for eigenvalue ``lam``: of its two closed forms
    the longer (the other vanishes when the Hessian is near diagonal)."""
    ux, uy = b, lam - a
    vx, vy = lam - c, b
    first = ux * ux + uy * uy >= vx * vx + vy * vy
    nx, ny = np.where(first, ux, vx), np.where(first, uy, vy)
    norm = np.sqrt(nx * nx + ny * ny)
    norm[norm == 0] = 1
    return nx / norm, ny / norm


def _points(d: dict[str, np.ndarray], iy: np.ndarray, ix: np.ndarray, nx: np.ndarray,
            ny: np.ndarray, t: np.ndarray, lam: np.ndarray, sigma: float, background: float,
            noise: float, params: StripeParams) -> StripePoints:
    strength = -lam.astype(np.float64)
    rv = d["v"][iy, ix].astype(np.float64)
    width = np.sqrt(np.clip((rv - background) / strength - sigma * sigma, 0.0, None))
    t64 = t.astype(np.float64)
    points = StripePoints(np.column_stack([ix + t64 * nx, iy + t64 * ny]),
                          np.column_stack([nx, ny]).astype(np.float64), strength, width,
                          background, noise, peak=rv - background)
    return reject_weak(points, params)


def _strength_limit(noise: float, sigma: float, params: StripeParams) -> np.float32:
    return np.float32(params.min_strength_sigma * max(noise, 1e-6)
                      * math.sqrt(3.0 / (16.0 * math.pi)) / sigma**3)


def _inside(shape: tuple[int, int], r: int) -> np.ndarray:
    sel = np.zeros(shape, bool)
    sel[r:-r, r:-r] = True
    return sel


def plain_steger(image: np.ndarray, params: StripeParams) -> StripePoints:
    """Steger's centres over the whole frame with his acceptance test, nothing more."""
    s = float(params.sigma_px)
    img, d = _filters(image, s)
    background, noise = _statistics(img)
    half_tr = 0.5 * (d["xx"] + d["yy"])
    root = np.sqrt((0.5 * (d["xx"] - d["yy"])) ** 2 + d["xy"] ** 2)
    lam_lo, lam_hi = half_tr - root, half_tr + root
    nx, ny = _normal(d["xx"], d["xy"], d["yy"], lam_lo)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -(nx * d["x"] + ny * d["y"]) / lam_lo
    ok = ((lam_lo < -_strength_limit(noise, s, params)) & (np.abs(lam_lo) > np.abs(lam_hi))
          & (np.abs(t * nx) <= _HALF_PIXEL) & (np.abs(t * ny) <= _HALF_PIXEL)
          & _inside(img.shape, max(1, math.ceil(4.0 * s))))
    iy, ix = np.nonzero(ok)
    return _points(d, iy, ix, nx[iy, ix], ny[iy, ix], t[iy, ix], lam_lo[iy, ix], s,
                   background, noise, params)


def plain_steger_pruned(image: np.ndarray, params: StripeParams) -> StripePoints:
    """``plain_steger`` with the eigenvector and offset only where the strength test passes."""
    s = float(params.sigma_px)
    img, d = _filters(image, s)
    background, noise = _statistics(img)
    half_tr = 0.5 * (d["xx"] + d["yy"])
    root = cv2.magnitude(0.5 * (d["xx"] - d["yy"]), d["xy"])
    lam_lo = half_tr - root
    strong = (lam_lo < -_strength_limit(noise, s, params)) & (np.abs(lam_lo) > np.abs(
        half_tr + root)) & _inside(img.shape, max(1, math.ceil(4.0 * s)))
    iy, ix = np.nonzero(strong)
    xx, yy, xy, lam = (a[iy, ix] for a in (d["xx"], d["yy"], d["xy"], lam_lo))
    nx, ny = _normal(xx, xy, yy, lam)
    t = -(nx * d["x"][iy, ix] + ny * d["y"][iy, ix]) / lam
    keep = (np.abs(t * nx) <= _HALF_PIXEL) & (np.abs(t * ny) <= _HALF_PIXEL)
    return _points(d, iy[keep], ix[keep], nx[keep], ny[keep], t[keep], lam[keep], s,
                   background, noise, params)
