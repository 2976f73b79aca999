"""Shop-floor disturbances for the simulated rig: what chips, coolant, stray light and the turned
surface itself add to a clean stripe image.

Each family is switchable (off by default) and seeded by the frame's generator, so frame ``i``
of a renderer is always the same image:

- ``Glints``: chips and coolant catching the laser, small (often saturated) blobs near the
  stripe and on it;
- ``Ghost``: a secondary reflection, a fainter, blurred copy of the stripe a few pixels away;
- ``Droplets``: coolant drops on the surface: the stripe is cut where they sit, their rims
  light up;
- ``Background``: a light gradient, a bright machine edge crossing the frame, a second bright
  object;
- ``exposure``: the stripe over-exposed by this factor (its core clips at 255);
- ``FeedMarks``: the turned surface's feed marks, a helical radius modulation along the axis
  (applied by the renderer where the light hits the surface, ``drivers.sim.rig``).

Images here are float32 grey levels (DN) before the sensor's noise and clipping; positions are
pixels. Parameters given as ``(low, high)`` are drawn uniformly per blob or per frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields

import cv2
import numpy as np

Range = tuple[float, float]


@dataclass(frozen=True)
class Glints:
    """Specular glints: ``count`` Gaussian blobs per frame, ``on_stripe`` of them on the
    stripe, the rest within ``spread_px`` of it."""

    count: int = 0
    sigma_px: Range = (0.7, 2.5)
    peak_dn: Range = (150.0, 1500.0)
    spread_px: float = 30.0
    on_stripe: float = 0.3


@dataclass(frozen=True)
class Ghost:
    """A secondary reflection: the stripe times ``gain``, blurred by ``blur_px`` and moved by
    ``offset_px`` (dx, dy)."""

    gain: float = 0.0
    offset_px: tuple[float, float] = (0.0, 6.0)
    blur_px: float = 1.5


@dataclass(frozen=True)
class Droplets:
    """``count`` coolant drops per frame on the stripe: inside each the light falls to
    ``transmission``; a rim ``rim_px`` wide shines at ``rim_dn`` where the laser lights it."""

    count: int = 0
    radius_px: Range = (2.0, 7.0)
    transmission: float = 0.1
    rim_px: float = 1.0
    rim_dn: Range = (60.0, 200.0)


@dataclass(frozen=True)
class Background:
    """Stray light: a linear ``gradient_dn`` across the frame, a bright edge of ``edge_dn`` (a
    lit machine part: a band ``edge_width_px`` wide crossing the frame with sharp sides), a
    second bright object of ``object_dn`` (an ellipse of ``object_radius_px``)."""

    gradient_dn: float = 0.0
    edge_dn: float = 0.0
    edge_width_px: Range = (15.0, 60.0)
    object_dn: float = 0.0
    object_radius_px: Range = (25.0, 80.0)


@dataclass(frozen=True)
class FeedMarks:
    """The turned surface: its radius varies by ``amplitude_um`` (peak) with the feed
    ``period_mm`` along the axis; the helix's phase changes from frame to frame."""

    amplitude_um: float = 0.0
    period_mm: float = 0.2


@dataclass(frozen=True)
class Disturbances:
    """Every shop-floor disturbance of a frame (all off by default)."""

    glints: Glints = field(default_factory=Glints)
    ghost: Ghost = field(default_factory=Ghost)
    droplets: Droplets = field(default_factory=Droplets)
    background: Background = field(default_factory=Background)
    exposure: float = 1.0
    feed_marks: FeedMarks = field(default_factory=FeedMarks)

    def __bool__(self) -> bool:
        return self != Disturbances()

    @classmethod
    def from_dict(cls, spec: dict) -> Disturbances:
        """From a JSON-like dict (``{"glints": {"count": 6}, "exposure": 2.5}``); unknown
        names raise ``ValueError`` naming them."""
        kinds = {f.name: f.type for f in fields(cls)}
        parts: dict = {}
        for name, value in spec.items():
            if name not in kinds:
                raise ValueError(f"unknown disturbance {name!r}; known: {sorted(kinds)}")
            if name == "exposure":
                parts[name] = float(value)
                continue
            part_cls = {"glints": Glints, "ghost": Ghost, "droplets": Droplets,
                        "background": Background, "feed_marks": FeedMarks}[name]
            known = {f.name for f in fields(part_cls)}
            unknown = set(value) - known
            if unknown:
                raise ValueError(f"unknown {name} setting(s) {sorted(unknown)}; known: "
                                 f"{sorted(known)}")
            parts[name] = part_cls(**{k: tuple(v) if isinstance(v, list) else v
                                      for k, v in value.items()})
        return cls(**parts)


def _uniform(rng: np.random.Generator, r: Range, n: int | None = None):
    return rng.uniform(r[0], r[1], n)


def _stripe_pixels(stripe: np.ndarray, box: tuple[int, int]) -> np.ndarray:
    """Pixel positions (x, y) on the stripe's bright core, in the frame."""
    if stripe.size == 0:
        return np.empty((0, 2))
    ys, xs = np.nonzero(stripe > 0.5 * float(stripe.max()))
    return np.column_stack([xs + box[0], ys + box[1]]).astype(np.float64)


def _blob(img: np.ndarray, x: float, y: float, sigma: float, peak: float) -> None:
    h, w = img.shape
    r = math.ceil(4 * sigma)
    x0, x1 = max(0, int(x) - r), min(w, int(x) + r + 2)
    y0, y1 = max(0, int(y) - r), min(h, int(y) + r + 2)
    if x0 >= x1 or y0 >= y1:
        return
    gy, gx = np.mgrid[y0:y1, x0:x1]
    img[y0:y1, x0:x1] += peak * np.exp(-((gx - x) ** 2 + (gy - y) ** 2) / (2 * sigma**2))


def disturb_stripe(stripe: np.ndarray, spec: Disturbances, rng: np.random.Generator
                   ) -> np.ndarray:
    """The stripe's own disturbances, on its radiance box (DN): over-exposure and the ghost.

    The ghost is added to a box the same size: ``offset_px`` should stay within the box's
    margin (the renderer's box has 12 px and more)."""
    out = stripe * np.float32(spec.exposure) if spec.exposure != 1.0 else stripe.copy()
    g = spec.ghost
    if g.gain > 0 and stripe.size:
        copy = cv2.GaussianBlur(stripe, (0, 0), g.blur_px) if g.blur_px > 0 else stripe
        m = np.float32([[1, 0, g.offset_px[0]], [0, 1, g.offset_px[1]]])
        moved = cv2.warpAffine(copy, m, (stripe.shape[1], stripe.shape[0]),
                               flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
        out += np.float32(g.gain * spec.exposure) * moved
    return out


def disturb_frame(img: np.ndarray, stripe: np.ndarray, box: tuple[int, int],
                  spec: Disturbances, rng: np.random.Generator) -> None:
    """The frame's disturbances, in place on ``img`` (the whole frame, DN, the stripe already
    in it): droplets, glints and stray light. ``stripe`` is the stripe's noise-free radiance
    on its box, whose top-left corner is ``box`` (x, y)."""
    h, w = img.shape
    on = _stripe_pixels(stripe, box)
    d = spec.droplets
    if d.count and len(on):
        for x, y in on[rng.integers(0, len(on), d.count)]:
            rad = float(_uniform(rng, d.radius_px))
            rim = float(_uniform(rng, d.rim_dn))
            r = math.ceil(rad + d.rim_px + 2)
            x0, x1 = max(0, int(x) - r), min(w, int(x) + r + 1)
            y0, y1 = max(0, int(y) - r), min(h, int(y) + r + 1)
            yy, xx = np.mgrid[y0:y1, x0:x1]
            dist = np.hypot(xx - x, yy - y)
            patch = img[y0:y1, x0:x1]
            inside = dist <= rad
            patch[inside] *= np.float32(d.transmission)
            ring = np.exp(-0.5 * ((dist - rad) / max(d.rim_px, 0.3)) ** 2)
            patch += np.float32(rim) * ring.astype(np.float32)
    gl = spec.glints
    if gl.count and len(on):
        n_on = round(gl.count * gl.on_stripe)
        centres = on[rng.integers(0, len(on), gl.count)]
        angle = rng.uniform(0, 2 * math.pi, gl.count)
        reach = rng.uniform(3.0, max(gl.spread_px, 3.0), gl.count)
        reach[:n_on] = 0.0
        centres = centres + reach[:, None] * np.column_stack([np.cos(angle), np.sin(angle)])
        for (x, y), s, p in zip(centres, _uniform(rng, gl.sigma_px, gl.count),
                                _uniform(rng, gl.peak_dn, gl.count), strict=True):
            _blob(img, float(x), float(y), float(s), float(p))
    b = spec.background
    if b.gradient_dn or b.edge_dn or b.object_dn:
        yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
        if b.gradient_dn:
            a = rng.uniform(0, 2 * math.pi)
            ramp = (xx - w / 2) * math.cos(a) + (yy - h / 2) * math.sin(a)
            img += np.float32(b.gradient_dn) * (ramp / float(np.abs(ramp).max()) + 1) / 2
        if b.edge_dn:
            # A straight band through a random point of the frame's outer third.
            a = rng.uniform(0, math.pi)
            px, py = rng.uniform(0, w), rng.choice([rng.uniform(0, h / 3),
                                                    rng.uniform(2 * h / 3, h)])
            across = (xx - px) * -math.sin(a) + (yy - py) * math.cos(a)
            half = float(_uniform(rng, b.edge_width_px)) / 2
            img += np.float32(b.edge_dn) * (np.abs(across) <= half).astype(np.float32)
        if b.object_dn:
            r = float(_uniform(rng, b.object_radius_px))
            ox, oy = rng.uniform(r, w - r), rng.uniform(r, h - r)
            blob = ((xx - ox) / r) ** 2 + ((yy - oy) / (0.6 * r)) ** 2 <= 1.0
            img += np.float32(b.object_dn) * cv2.GaussianBlur(
                blob.astype(np.float32), (0, 0), 1.0)


def feed_mark_shift_mm(axial_mm: np.ndarray, marks: FeedMarks, phase: float) -> np.ndarray:
    """Radial displacement of the turned surface at axial positions ``axial_mm``, mm."""
    if not marks.amplitude_um:
        return np.zeros_like(axial_mm)
    return 1e-3 * marks.amplitude_um * np.cos(2 * math.pi * axial_mm / marks.period_mm + phase)


# The families of the robustness bench and the tests: one development setting each; the
# held-out settings (``HELD_OUT``) are scored only at the end.
FAMILIES: dict[str, Disturbances] = {
    "clean": Disturbances(),
    "glints": Disturbances(glints=Glints(count=8)),
    "ghost": Disturbances(ghost=Ghost(gain=0.35, offset_px=(0.0, 6.0), blur_px=1.5)),
    "droplets": Disturbances(droplets=Droplets(count=3)),
    "background": Disturbances(background=Background(gradient_dn=40.0, edge_dn=90.0,
                                                     object_dn=120.0)),
    "overexposed": Disturbances(exposure=3.0),
    "feed_marks": Disturbances(feed_marks=FeedMarks(amplitude_um=2.0, period_mm=0.15)),
}
FAMILIES["combined"] = Disturbances(
    glints=Glints(count=5), ghost=Ghost(gain=0.25, offset_px=(2.0, -5.0), blur_px=2.0),
    droplets=Droplets(count=2), background=Background(gradient_dn=30.0, edge_dn=70.0),
    exposure=2.0, feed_marks=FeedMarks(amplitude_um=1.5, period_mm=0.25))

HELD_OUT: dict[str, Disturbances] = {
    "glints": Disturbances(glints=Glints(count=14, sigma_px=(1.0, 3.5), spread_px=45.0,
                                         on_stripe=0.4)),
    "ghost": Disturbances(ghost=Ghost(gain=0.5, offset_px=(-4.0, 4.0), blur_px=1.0)),
    "droplets": Disturbances(droplets=Droplets(count=5, radius_px=(3.0, 10.0))),
    "background": Disturbances(background=Background(gradient_dn=60.0, edge_dn=140.0,
                                                     edge_width_px=(8.0, 25.0),
                                                     object_dn=180.0)),
    "overexposed": Disturbances(exposure=5.0),
    "feed_marks": Disturbances(feed_marks=FeedMarks(amplitude_um=4.0, period_mm=0.1)),
    "combined": Disturbances(
        glints=Glints(count=10), ghost=Ghost(gain=0.4, offset_px=(-3.0, 5.0)),
        droplets=Droplets(count=4), background=Background(gradient_dn=50.0, object_dn=150.0),
        exposure=3.5, feed_marks=FeedMarks(amplitude_um=3.0, period_mm=0.3)),
}
