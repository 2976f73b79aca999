"""Following slow drift of the spindle axis (thermal growth of the camera mount) in the section.

Every frame's free (geometric) fit gives a section centre with a covariance that is large
along the arc's bisector, where centre and radius trade off, and small across it. Free-fit
centres are biased by the stripe's systematic errors, and that bias depends on the diameter;
followed as they are, they would pull the axis method back to the free fit's accuracy. So the
tracker follows *changes*: for each diameter band it takes the median of the first
``reference_frames`` free centres as a reference, then an exponentially weighted mean of the
later ones (time constant ``time_constant_frames``) tells how far the axis moved since. Frames
whose free centre lies beyond ``gate`` sigmas (Mahalanobis) of that mean are rejected, so no
single bad frame moves it. A change of band starts a new reference and carries the drift so
far over. While a reference is being made, a free centre that disagrees with the centre
tracked so far beyond ``gate`` sigmas (its covariance and the tracked centre's sigma) is not
taken either: a frame whose free fit went astray (a ghost, a glint) does not become a
reference.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np


@dataclass
class AxisTracker:
    """Tracked section centre = calibrated (or mastered) centre + drift.

    Parameters
    ----------
    base_center : ndarray, shape (2,)
        Calibrated or mastered axis in section coordinates, mm.
    base_sigma_mm : float
        Its standard deviation, mm.
    reference_frames : int
        Free-fit centres that make the reference of a diameter band.
    time_constant_frames : float
        Memory of the drift estimate, frames.
    gate : float
        Rejection threshold, Mahalanobis sigmas.
    band_mm : float
        Width of a diameter band, mm.
    """

    base_center: np.ndarray
    base_sigma_mm: float = 0.001
    reference_frames: int = 30
    time_constant_frames: float = 300.0
    gate: float = 4.0
    band_mm: float = 0.5
    accepted: int = 0
    rejected: int = 0
    _drift: np.ndarray = field(default_factory=lambda: np.zeros(2))
    _carried: np.ndarray = field(default_factory=lambda: np.zeros(2))
    _band: int | None = None
    _ref: np.ndarray | None = None
    _ref_buf: list[np.ndarray] = field(default_factory=list)
    _mean: np.ndarray | None = None
    _mean_cov: np.ndarray = field(default_factory=lambda: np.eye(2))

    def update(self, free_center: np.ndarray, free_cov: np.ndarray, diameter_mm: float
               ) -> bool:
        """Take one frame's free-fit centre (mm) and covariance (mm^2); False if rejected."""
        c = np.asarray(free_center, np.float64)
        cov = np.asarray(free_cov, np.float64)
        if not (np.isfinite(c).all() and np.isfinite(cov).all() and math.isfinite(diameter_mm)):
            self.rejected += 1
            return False
        band = math.floor(diameter_mm / self.band_mm)
        if band != self._band:
            self._carried = self._drift.copy()
            self._band, self._ref, self._ref_buf, self._mean = band, None, [], None
        if self._ref is None:
            tracked, sigma = self.center()
            if not self._within_gate(c - tracked, cov + sigma**2 * np.eye(2)):
                self.rejected += 1
                return False
            self._ref_buf.append(c)
            if len(self._ref_buf) >= self.reference_frames:
                self._ref = np.median(np.array(self._ref_buf), axis=0)
                self._mean = self._ref.copy()
                self._mean_cov = cov / max(len(self._ref_buf), 1)
            self.accepted += 1
            return True
        innovation = c - self._mean
        if not self._within_gate(innovation, cov + self._mean_cov):
            self.rejected += 1
            return False
        k = 1.0 / self.time_constant_frames
        self._mean = self._mean + k * innovation
        self._mean_cov = (1 - k) ** 2 * self._mean_cov + k**2 * cov
        self._drift = self._carried + (self._mean - self._ref)
        self.accepted += 1
        return True

    def _within_gate(self, innovation: np.ndarray, cov: np.ndarray) -> bool:
        try:
            m2 = float(innovation @ np.linalg.solve(cov, innovation))
        except np.linalg.LinAlgError:
            return False
        return m2 <= self.gate**2

    def center(self) -> tuple[np.ndarray, float]:
        """(tracked centre in section mm, its standard deviation mm)."""
        track_var = float(np.trace(self._mean_cov)) / 2.0 if self._ref is not None else 0.0
        return (np.asarray(self.base_center, np.float64) + self._drift,
                math.sqrt(self.base_sigma_mm**2 + track_var))

    @property
    def drift_mm(self) -> np.ndarray:
        """Drift of the axis since calibration, section mm."""
        return self._drift.copy()
