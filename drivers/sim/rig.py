"""A simulated structured-light rig: renders 8-bit stripe images of a turned shaft, and returns
the exact calibration that goes with them.

The model, in the *lathe frame* (spindle axis = X, through the origin):

- a pinhole camera with OpenCV distortion, ``standoff_mm`` from the axis on the -Z side, looking
  at the shaft, slightly misaligned by ``misalignment_deg`` (rotations about x, y, z);
- a light sheet through the origin whose plane makes ``triangulation_deg`` with the camera's
  viewing direction, with a Gaussian thickness profile (``sheet_sigma_mm``), fanned from a
  laser source ``laser_distance_mm`` from the axis at ``laser_azimuth_deg`` around it (0 is the
  camera's side): the azimuth sets how much of the lit section the camera sees;
- a cylinder of the given diameter; Lambertian shading from the laser source; a faint ambient
  light on the shaft body; ray casting per pixel (the first hit on the cylinder);
- laser speckle (a multiplicative, spatially correlated field of given contrast and grain that
  changes from frame to frame as the shaft turns), optical blur, shot and read noise;
- optionally a turned surface that is not concentric with the spindle or not round
  (``Turning``: eccentricity and its phase, lobes), carried round by the spindle: a frame is
  rendered at a spindle angle;
- optionally the shop floor's disturbances (``drivers.sim.disturb``: glints, a ghost stripe,
  coolant droplets, stray light, over-exposure, feed marks), drawn from their own generator so
  that a disturbed frame has the same speckle and noise as its clean twin.

Everything is deterministic for a given seed and frame index.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from calib_store.model import SCHEMA, Calibration, parse_calibration
from drivers.sim.disturb import Disturbances, disturb_frame, disturb_stripe, feed_mark_shift_mm
from service.measure.section import first_hit_on_cylinder, orthonormal_basis


def _rotation(rx_deg: float, ry_deg: float, rz_deg: float) -> np.ndarray:
    rx, ry, rz = (math.radians(a) for a in (rx_deg, ry_deg, rz_deg))
    cx, sx, cy, sy, cz, sz = math.cos(rx), math.sin(rx), math.cos(ry), math.sin(ry), \
        math.cos(rz), math.sin(rz)
    mx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    my = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    mz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return mz @ my @ mx


@dataclass(frozen=True)
class Turning:
    """The surface under the laser as the spindle carries it round.

    Angles count right-handed about the spindle axis (the calibration's ``axis.direction``,
    the lathe's +X) from the lathe's +Y toward +Z; at spindle angle ``theta`` the material has
    turned by ``theta`` that way.

    Attributes
    ----------
    eccentricity_mm : float
        How far the surface's own axis lies from the spindle's (raw stock, a second clamping):
        the dial indicator's TIR is twice it.
    eccentricity_deg : float
        The direction of that offset at spindle angle 0.
    lobes : tuple of (int, float, float)
        The radius's harmonics over the material's angle: (order, amplitude_mm, phase_deg),
        ``r(beta) = R + sum a cos(k beta - phase)``.
    """

    eccentricity_mm: float = 0.0
    eccentricity_deg: float = 0.0
    lobes: tuple[tuple[int, float, float], ...] = ()

    def __bool__(self) -> bool:
        return bool(self.eccentricity_mm) or any(a for _, a, _ in self.lobes)

    def center_offset_mm(self, spindle_deg: float) -> tuple[float, float]:
        """The surface's centre off the spindle axis at a spindle angle, (Y, Z) mm."""
        a = math.radians(self.eccentricity_deg + spindle_deg)
        return self.eccentricity_mm * math.cos(a), self.eccentricity_mm * math.sin(a)

    def radius_shift_mm(self, section_rad: np.ndarray, spindle_deg: float) -> np.ndarray:
        """The radius less the mean radius at section angles (about the surface's centre,
        rad) at a spindle angle, mm."""
        beta = section_rad - math.radians(spindle_deg)  # the material's angle
        out = np.zeros_like(section_rad)
        for order, amplitude, phase in self.lobes:
            out += amplitude * np.cos(order * beta - math.radians(phase))
        return out


@dataclass(frozen=True)
class RigConfig:
    """Geometry, optics and noise of the simulated rig (defaults: like the paper's rig).

    Lengths in mm, angles in degrees, grey levels (DN) of an 8-bit image.
    """

    image_size: tuple[int, int] = (1376, 1024)
    focal_mm: float = 25.0
    pixel_um: float = 6.45
    principal_offset_px: tuple[float, float] = (4.0, -3.0)
    dist_coeffs: tuple[float, ...] = (-0.12, 0.25, 0.0004, -0.0003, 0.0)
    standoff_mm: float = 300.0
    misalignment_deg: tuple[float, float, float] = (1.2, -1.5, 0.8)
    triangulation_deg: float = 35.0
    laser_azimuth_deg: float = 55.0
    laser_distance_mm: float = 250.0
    sheet_sigma_mm: float = 0.06
    blur_px: float = 0.7
    speckle_contrast: float = 0.25
    speckle_grain_px: float = 1.2
    peak_dn: float = 160.0
    ambient_dn: float = 10.0
    background_dn: float = 3.0
    electrons_per_dn: float = 8.0
    read_noise_dn: float = 1.2
    axis_offset_mm: tuple[float, float] = (0.0, 0.0)
    """Where the shaft's axis actually is (Y, Z in the lathe frame) relative to the calibrated
    spindle axis: zero for a part turned on this lathe."""
    disturbances: Disturbances = field(default_factory=Disturbances)
    """The shop floor's disturbances (none by default)."""
    turning: Turning = field(default_factory=Turning)
    """A surface not concentric with the spindle or not round (none by default: a surface
    turned on this lathe)."""

    @property
    def focal_px(self) -> float:
        """Focal length in pixels."""
        return self.focal_mm / self.pixel_um * 1000.0

    def camera_matrix(self) -> np.ndarray:
        """OpenCV intrinsic matrix, px."""
        w, h = self.image_size
        f = self.focal_px
        cx = (w - 1) / 2.0 + self.principal_offset_px[0]
        cy = (h - 1) / 2.0 + self.principal_offset_px[1]
        return np.array([[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]])

    def with_(self, **changes: object) -> RigConfig:
        """A copy with some fields changed."""
        return replace(self, **changes)


@dataclass(frozen=True)
class _Pose:
    """Lathe-to-camera transform ``X_c = R (X_l - C)`` and the rig's light in the camera frame."""

    R: np.ndarray
    C: np.ndarray
    plane_normal: np.ndarray
    plane_d: float
    laser_source: np.ndarray
    axis_direction: np.ndarray
    axis_point: np.ndarray


def _pose(cfg: RigConfig) -> _Pose:
    R = _rotation(*cfg.misalignment_deg)
    C = np.array([0.0, 0.0, -cfg.standoff_mm])
    beta = math.radians(cfg.triangulation_deg)
    n_l = np.array([math.cos(beta), 0.0, math.sin(beta)])  # plane through the lathe origin
    phi = math.radians(cfg.laser_azimuth_deg)
    rho = cfg.laser_distance_mm
    y_s, z_s = rho * math.sin(phi), -rho * math.cos(phi)
    x_s = -(n_l[2] * z_s) / n_l[0]
    source_l = np.array([x_s, y_s, z_s])

    def to_cam(p: np.ndarray) -> np.ndarray:
        return R @ (p - C)

    n_c = R @ n_l
    d_c = float(n_c @ to_cam(np.zeros(3)))
    a_c = R @ np.array([1.0, 0.0, 0.0])
    # The calibration's axis point: where the spindle axis crosses the light plane (the
    # lathe origin, by construction).
    return _Pose(R, C, n_c, d_c, to_cam(source_l), a_c, to_cam(np.zeros(3)))


def rig_calibration(cfg: RigConfig) -> Calibration:
    """The exact calibration of the simulated rig, in the interchange format."""
    pose = _pose(cfg)

    def unit(v: np.ndarray) -> list[float]:
        v = np.asarray(v, np.float64)
        return [float(x) for x in v / np.linalg.norm(v)]

    return parse_calibration({
        "schema": SCHEMA,
        "units": "mm",
        "image_size": [int(cfg.image_size[0]), int(cfg.image_size[1])],
        "camera_matrix": [[float(x) for x in row] for row in cfg.camera_matrix()],
        "dist_coeffs": [float(x) for x in cfg.dist_coeffs],
        "light_plane": {"normal": unit(pose.plane_normal), "d": pose.plane_d},
        "axis": {"direction": unit(pose.axis_direction),
                 "point": [float(x) for x in pose.axis_point]},
    })


@functools.lru_cache(maxsize=4)
def _ray_grid(image_size: tuple[int, int], camera_matrix: tuple[float, ...],
              dist_coeffs: tuple[float, ...], step: int) -> np.ndarray:
    """Undistorted normalised ray (x, y) of every ``step``-th pixel centre, shape (H', W', 2)."""
    w, h = image_size
    xs = np.arange(0, w, step, dtype=np.float64)
    ys = np.arange(0, h, step, dtype=np.float64)
    gx, gy = np.meshgrid(xs, ys)
    pts = np.column_stack([gx.ravel(), gy.ravel()]).reshape(-1, 1, 2)
    K = np.array(camera_matrix, np.float64).reshape(3, 3)
    out = cv2.undistortPointsIter(pts, K, np.array(dist_coeffs, np.float64), None, None,
                                  (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-12))
    return out.reshape(len(ys), len(xs), 2)


@dataclass
class ShaftRenderer:
    """Renders frames of one rig; caches what does not change between frames.

    Parameters
    ----------
    config : RigConfig
        The rig.
    seed : int
        Seed of the speckle and noise; frame ``i`` of a renderer with seed ``s`` is always the
        same image.
    """

    config: RigConfig = field(default_factory=RigConfig)
    seed: int = 0

    def __post_init__(self) -> None:
        self._pose = _pose(self.config)
        self._calibration = rig_calibration(self.config)
        self._base_cache: dict[tuple[float, float],
                               tuple[np.ndarray, tuple[int, int, int, int]]] = {}
        self._ambient_cache: dict[float, np.ndarray] = {}

    @property
    def calibration(self) -> Calibration:
        """The exact calibration of this rig."""
        return self._calibration

    def _rays(self, step: int) -> np.ndarray:
        cfg = self.config
        return _ray_grid(tuple(cfg.image_size), tuple(cfg.camera_matrix().ravel()),
                         tuple(cfg.dist_coeffs), step)

    def _axis_point(self, spindle_deg: float = 0.0) -> np.ndarray:
        """A point on the surface's own axis at a spindle angle, camera frame, mm."""
        cfg, p = self.config, self._pose
        dy, dz = cfg.turning.center_offset_mm(spindle_deg)
        off = np.array([0.0, cfg.axis_offset_mm[0] + dy, cfg.axis_offset_mm[1] + dz])
        return p.R @ (off - p.C)

    def _hit(self, rays_xy: np.ndarray, radius: float, spindle_deg: float = 0.0
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """First intersection of camera rays with the shaft: (hit mask, points, normals)."""
        return first_hit_on_cylinder(rays_xy, self._axis_point(spindle_deg),
                                     self._pose.axis_direction, radius)

    def _stripe_roi(self, radius: float, spindle_deg: float = 0.0
                    ) -> tuple[int, int, int, int]:
        """Pixel bounding box (x0, y0, x1, y1) of the lit section, with a margin."""
        p = self._pose
        cfg = self.config
        t = np.linspace(0, 2 * math.pi, 721)
        e1, e2 = orthonormal_basis(p.axis_direction)
        a0 = self._axis_point(spindle_deg)
        ring = a0 + radius * (np.cos(t)[:, None] * e1 + np.sin(t)[:, None] * e2)
        # Slide each ring point along the axis onto the light plane.
        k = (p.plane_d - ring @ p.plane_normal) / (p.axis_direction @ p.plane_normal)
        on_plane = ring + k[:, None] * p.axis_direction
        on_plane = on_plane[on_plane[:, 2] > 1.0]
        img, _ = cv2.projectPoints(on_plane, np.zeros(3), np.zeros(3), cfg.camera_matrix(),
                                   np.array(cfg.dist_coeffs))
        img = img.reshape(-1, 2)
        lobes = sum(abs(a) for _, a, _ in cfg.turning.lobes)
        margin = (4.0 * cfg.sheet_sigma_mm + 2.0 * lobes) * cfg.focal_px / cfg.standoff_mm + 12
        w, h = cfg.image_size
        x0 = int(max(0, math.floor(img[:, 0].min() - margin)))
        x1 = int(min(w, math.ceil(img[:, 0].max() + margin)))
        y0 = int(max(0, math.floor(img[:, 1].min() - margin)))
        y1 = int(min(h, math.ceil(img[:, 1].max() + margin)))
        return x0, y0, max(x0, x1), max(y0, y1)

    def _stripe_radiance(self, diameter_mm: float, phase: float = 0.0,
                         spindle_deg: float = 0.0
                         ) -> tuple[np.ndarray, tuple[int, int, int, int]]:
        """Noise-free stripe radiance in DN over its ROI (cached per diameter, feed-mark
        phase, rad, and spindle angle)."""
        cfg, p = self.config, self._pose
        if not cfg.turning:
            spindle_deg = 0.0
        key = (round(float(diameter_mm), 9), round(phase, 6), round(spindle_deg % 360.0, 6))
        if key in self._base_cache:
            return self._base_cache[key]
        radius = diameter_mm / 2.0
        x0, y0, x1, y1 = self._stripe_roi(radius, spindle_deg)
        rays = self._rays(1)[y0:y1, x0:x1]
        hit, pts, nrm = self._hit(rays, radius, spindle_deg)
        marks = cfg.disturbances.feed_marks
        a0 = self._axis_point(spindle_deg)
        dr = np.zeros(pts.shape[:-1])
        if marks.amplitude_um:
            dr = dr + feed_mark_shift_mm((pts - a0) @ p.axis_direction, marks, phase)
        if cfg.turning.lobes:
            rel = pts - a0
            ey, ez = p.R @ np.array([0.0, 1.0, 0.0]), p.R @ np.array([0.0, 0.0, 1.0])
            dr = dr + cfg.turning.radius_shift_mm(np.arctan2(rel @ ez, rel @ ey), spindle_deg)
        if marks.amplitude_um or cfg.turning.lobes:
            # The surface lies dr further out: a ray meets it dr / cos(view angle) earlier.
            ray = pts / np.linalg.norm(pts, axis=-1, keepdims=True)
            cos_view = np.maximum(-np.sum(nrm * ray, axis=-1), 0.05)
            pts = pts - ray * (np.nan_to_num(dr) / cos_view)[..., None]
        dist = pts @ p.plane_normal - p.plane_d
        to_src = p.laser_source - pts
        to_src /= np.linalg.norm(to_src, axis=-1, keepdims=True)
        cos_inc = np.clip(np.sum(nrm * to_src, axis=-1), 0.0, None)
        rad = cfg.peak_dn * np.exp(-0.5 * (dist / cfg.sheet_sigma_mm) ** 2) * cos_inc
        rad = np.where(hit, rad, 0.0).astype(np.float32)
        if len(self._base_cache) > 16:
            self._base_cache.clear()
        self._base_cache[key] = (rad, (x0, y0, x1, y1))
        return rad, (x0, y0, x1, y1)

    def _ambient(self, diameter_mm: float) -> np.ndarray:
        """Faint light on the shaft body over the background, full frame, DN (cached)."""
        key = round(float(diameter_mm), 3)
        if key not in self._ambient_cache:
            cfg = self.config
            step = 4
            hit, _, nrm = self._hit(self._rays(step), diameter_mm / 2.0)
            shade = np.where(hit, cfg.ambient_dn * np.clip(-nrm[..., 2], 0.0, 1.0), 0.0)
            w, h = cfg.image_size
            full = cv2.resize(shade.astype(np.float32), (w, h), interpolation=cv2.INTER_LINEAR)
            if len(self._ambient_cache) > 8:
                self._ambient_cache.clear()
            self._ambient_cache[key] = full + np.float32(cfg.background_dn)
        return self._ambient_cache[key]

    def render(self, diameter_mm: float, frame_index: int = 0,
               spindle_deg: float = 0.0) -> np.ndarray:
        """One 8-bit stripe image of a shaft of ``diameter_mm``.

        Parameters
        ----------
        diameter_mm : float
            Shaft diameter, mm (twice the mean radius).
        frame_index : int
            Frame number; speckle and noise change with it (the shaft turns).
        spindle_deg : float
            The spindle's angle (``Turning``): where an eccentric or lobed surface stands.

        Returns
        -------
        ndarray of uint8, shape (H, W)
        """
        cfg = self.config
        spec = cfg.disturbances
        rng = np.random.default_rng([self.seed, int(frame_index)])
        # The feed marks' helix turns with the shaft: one of 8 phases per frame.
        phase = 2 * math.pi * (int(frame_index) % 8) / 8 if spec.feed_marks.amplitude_um else 0.0
        rad, (x0, y0, x1, y1) = self._stripe_radiance(diameter_mm, phase, spindle_deg)
        rng_shop = np.random.default_rng([self.seed, int(frame_index), 1])
        img = self._ambient(diameter_mm).copy()
        if rad.size:
            roi = self._speckled(rad, rng)
            if spec:
                roi = disturb_stripe(roi, spec, rng_shop)
            if cfg.blur_px > 0:
                roi = cv2.GaussianBlur(roi, (0, 0), cfg.blur_px)
            img[y0:y1, x0:x1] += roi
        if spec:
            disturb_frame(img, rad, (x0, y0), spec, rng_shop)
        sigma = np.sqrt(img / cfg.electrons_per_dn + cfg.read_noise_dn**2)
        img += sigma * rng.standard_normal(img.shape, dtype=np.float32)
        return np.clip(np.rint(img), 0, 255).astype(np.uint8)

    def _speckled(self, rad: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """``rad`` times the frame's speckle (the first draw of the frame's generator)."""
        cfg = self.config
        if not cfg.speckle_contrast > 0:
            return rad
        field_ = rng.standard_normal(rad.shape, dtype=np.float32)
        field_ = cv2.GaussianBlur(field_, (0, 0), max(cfg.speckle_grain_px, 0.3))
        field_ /= max(float(field_.std()), 1e-6)
        return rad * np.clip(1.0 + cfg.speckle_contrast * field_, 0.0, None)

    def stripe_light(self, diameter_mm: float, frame_index: int | None = None
                     ) -> tuple[np.ndarray, tuple[int, int]]:
        """The stripe's light as the lens forms it (blurred), DN, on its box, and the box's
        top-left pixel (x, y): with frame ``frame_index``'s speckle, or none when None. No
        feed marks, disturbances, ambient light or sensor noise: what an extractor could at
        best see of the stripe (the benches' speckle floor)."""
        cfg = self.config
        rad, (x0, y0, _, _) = self._stripe_radiance(diameter_mm)
        if frame_index is not None and rad.size:
            rad = self._speckled(rad, np.random.default_rng([self.seed, int(frame_index)]))
        if cfg.blur_px > 0 and rad.size:
            rad = cv2.GaussianBlur(rad, (0, 0), cfg.blur_px)
        return rad, (x0, y0)

    def render_clean(self, diameter_mm: float) -> np.ndarray:
        """The noise- and speckle-free float image (blurred), for tests of the extractor."""
        cfg = self.config
        rad, (x0, y0, x1, y1) = self._stripe_radiance(diameter_mm)
        img = np.zeros((cfg.image_size[1], cfg.image_size[0]), np.float32)
        roi = cv2.GaussianBlur(rad, (0, 0), cfg.blur_px) if cfg.blur_px > 0 else rad
        img[y0:y1, x0:x1] = roi
        return img
