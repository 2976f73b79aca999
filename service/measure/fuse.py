"""Many measurements into one: robust fusion over a window, and a master-part correction."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from service.measure.result import Measurement, Method, Status

_MAD_TO_SIGMA = 1.4826


@dataclass(frozen=True)
class Fused:
    """One diameter from a window of frames.

    Attributes
    ----------
    status : Status
        OK when at least ``min_frames`` good frames agreed.
    diameter_mm, uncertainty_mm : float or None
        Weighted mean of the kept frames and its standard uncertainty, mm.
    n_frames, n_used, n_rejected : int
        Frames given, good frames kept, good frames set aside as outliers.
    spread_mm : float or None
        Standard deviation of the kept frames' diameters, mm.
    reason : str
        Why there is no diameter.
    """

    status: Status
    method: Method
    diameter_mm: float | None
    uncertainty_mm: float | None
    n_frames: int
    n_used: int
    n_rejected: int
    spread_mm: float | None
    reason: str = ""

    def __bool__(self) -> bool:
        return self.status is Status.OK


def fuse(measurements: list[Measurement], min_frames: int = 3, reject_k: float = 3.5
         ) -> Fused:
    """Robust fusion: good frames only, outliers beyond ``reject_k`` robust sigmas of the median
    set aside, then the mean weighted by 1 / uncertainty^2.

    The fused uncertainty is the larger of the weighted-mean uncertainty and the observed
    scatter over sqrt(n), so that frames whose uncertainties are too small cannot make the
    result look better than its spread shows.

    Parameters
    ----------
    measurements : list of Measurement
        The window.
    min_frames : int
        Fewest good frames for a result.
    reject_k : float
        Outlier threshold in robust standard deviations (MAD).

    Returns
    -------
    Fused
    """
    n = len(measurements)
    method = measurements[0].method if measurements else Method.AXIS
    good = [m for m in measurements if m and m.diameter_mm is not None
            and math.isfinite(m.diameter_mm)]
    if len(good) < min_frames:
        return Fused(Status.TOO_FEW_POINTS, method, None, None, n, len(good), 0, None,
                     f"{len(good)} good frames of {n}, need {min_frames}")
    d = np.array([m.diameter_mm for m in good])
    u = np.array([m.uncertainty_mm if m.uncertainty_mm and m.uncertainty_mm > 0
                  else np.nan for m in good])
    if np.isnan(u).any():  # no per-frame uncertainty: equal weights
        u = np.full(len(d), float(np.std(d)) or 1e-6)
    med = float(np.median(d))
    mad = _MAD_TO_SIGMA * float(np.median(np.abs(d - med)))
    keep = np.abs(d - med) <= max(reject_k * mad, 1e-6)
    d, u = d[keep], u[keep]
    w = 1.0 / u**2
    mean = float(np.sum(w * d) / np.sum(w))
    formal = float(math.sqrt(1.0 / np.sum(w)))
    spread = float(np.std(d, ddof=1)) if len(d) > 1 else 0.0
    unc = max(formal, spread / math.sqrt(len(d)))
    return Fused(Status.OK, method, mean, unc, n, int(keep.sum()), int((~keep).sum()),
                 spread)


def master_offset(fused_master: Fused, certified_mm: float) -> tuple[float, float]:
    """Diameter correction from a master cylinder: (offset mm to add, its uncertainty mm)."""
    if not fused_master:
        raise ValueError(f"master measurement failed: {fused_master.reason}")
    return certified_mm - fused_master.diameter_mm, fused_master.uncertainty_mm
