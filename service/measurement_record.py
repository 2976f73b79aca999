"""One published measurement as the API, the registers and compensation see it: a pure
function of the frame's measurement and what was in force when the frame was taken."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, NamedTuple

from service.measure.result import Measurement
from service.measure.thermal import diameter_at_reference


class MeasurementRecord(NamedTuple):
    """One published measurement, as the API shows it (lengths in mm). Plain values only:
    the feed's history keeps them as plain tuples, which the cyclic collector leaves alone
    (``MeasurementFeed.history_newest_first``)."""

    seq: int
    time: float                 # wall clock, Unix seconds
    frame_id: int
    method: str
    status: str
    diameter_mm: float | None   # after the master correction
    raw_diameter_mm: float | None
    uncertainty_mm: float | None
    diameter_20c_mm: float | None
    fused_diameter_mm: float | None
    fused_uncertainty_mm: float | None
    deviation_mm: float | None  # from the nominal, when one is set
    in_tolerance: bool | None
    arc_deg: float
    n_points: int
    rms_residual_mm: float | None
    latency_ms: float           # frame received -> published
    reason: str
    note: str
    calibration_id: int | None = None  # the calibration it was measured with
    spindle_deg: float | None = None    # the frame's spindle angle, when known
    about_runout: bool = False          # measured about the surface's own centre there
    feature: int | None = None          # the job's feature it was taken as (None: none fits)

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready: a non-finite number (a fit's NaN residual, say) becomes None."""
        return {k: finite_or_none(v) if isinstance(v, float) else v
                for k, v in self._asdict().items()}

    @property
    def compensation_diameter_mm(self) -> float | None:
        """The diameter compensation judges: at 20 C when the part temperature is known."""
        return self.diameter_20c_mm if self.diameter_20c_mm is not None else self.diameter_mm


@dataclass(frozen=True)
class Feature:
    """What a measurement is compared with (mm)."""

    nominal_mm: float | None
    tol_lower_mm: float
    tol_upper_mm: float


def make_record(*, seq: int, wall_time: float, frame_id: int, raw: Measurement,
                m: Measurement, fused: Measurement | None, feature: Feature,
                part_temp_c: float | None, alpha_per_k: float, latency_ms: float,
                calibration_id: int | None, feature_number: int | None = None,
                refused: str = "") -> MeasurementRecord:
    """The record of one frame: ``raw`` as measured, ``m`` corrected, ``fused`` the fusion
    window's value; deviation and tolerance against ``feature`` (the job's feature
    ``feature_number``) at 20 C when the part's temperature is known. ``refused`` says why the
    diameter was taken as no feature of the job (then nothing is judged)."""
    d20 = (diameter_at_reference(m.diameter_mm, part_temp_c, alpha_per_k)
           if m and part_temp_c is not None else None)
    judged = d20 if d20 is not None else m.diameter_mm
    dev = judged - feature.nominal_mm if m and feature.nominal_mm is not None else None
    return MeasurementRecord(
        seq=seq, time=wall_time, frame_id=frame_id, method=m.method.value,
        status=m.status.value, diameter_mm=m.diameter_mm if m else None,
        raw_diameter_mm=raw.diameter_mm if m else None,
        uncertainty_mm=m.uncertainty_mm if m else None, diameter_20c_mm=d20,
        fused_diameter_mm=fused.diameter_mm if fused else None,
        fused_uncertainty_mm=fused.uncertainty_mm if fused else None,
        deviation_mm=dev,
        in_tolerance=None if dev is None else
        bool(feature.tol_lower_mm <= dev <= feature.tol_upper_mm),
        arc_deg=float(m.arc_deg or 0.0), n_points=m.n_points,
        rms_residual_mm=m.rms_residual_mm, latency_ms=latency_ms,
        reason=m.reason or refused, note=m.note, calibration_id=calibration_id,
        spindle_deg=m.spindle_deg, about_runout=m.about_runout, feature=feature_number)


def finite_or_none(x: float | None) -> float | None:
    """None for None, NaN and infinity."""
    return None if x is None or not math.isfinite(x) else x
