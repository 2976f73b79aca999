"""Mastering: a diameter correction from master cylinders of certified diameter.

One master gives an offset (``d = measured + offset``); two of different diameters give a
scale and an offset (``d = scale * measured + offset``). A master check measures a master with
the current correction and passes when the error is within a limit.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

from service.measure.result import Measurement


@dataclass(frozen=True)
class DiameterCorrection:
    """``d_corrected = scale * d_measured + offset_mm``."""

    offset_mm: float = 0.0
    scale: float = 1.0
    created: float = 0.0

    def apply(self, diameter_mm: float) -> float:
        """The corrected diameter, mm."""
        return self.scale * diameter_mm + self.offset_mm


def corrected(m: Measurement, correction: DiameterCorrection | None) -> Measurement:
    """The measurement with the master correction applied (its uncertainty scaled too)."""
    if not m or correction is None:
        return m
    return replace(m, diameter_mm=correction.apply(m.diameter_mm),
                   uncertainty_mm=None if m.uncertainty_mm is None
                   else m.uncertainty_mm * abs(correction.scale))


def correction_from_masters(masters: list[tuple[float, float]]) -> DiameterCorrection:
    """From (certified mm, measured mm) pairs: one gives an offset, two a scale and offset.

    Raises
    ------
    ValueError
        No master, more than two, or two of the same diameter.
    """
    if len(masters) == 1:
        certified, measured = masters[0]
        return DiameterCorrection(certified - measured, 1.0, time.time())
    if len(masters) == 2:
        (c1, m1), (c2, m2) = masters
        if abs(c2 - c1) < 1.0 or abs(m2 - m1) < 1.0:
            raise ValueError("two masters must differ in diameter by at least 1 mm")
        scale = (c2 - c1) / (m2 - m1)
        if not 0.99 < scale < 1.01:
            raise ValueError(f"the masters give a scale of {scale:.5f}: more than 1% from 1 "
                             "means a wrong certificate or a bad calibration")
        return DiameterCorrection(c1 - scale * m1, scale, time.time())
    raise ValueError("mastering takes one master (offset) or two (offset and scale)")


@dataclass(frozen=True)
class MasterCheck:
    """The outcome of measuring a master with the current correction."""

    certified_mm: float
    measured_mm: float
    error_mm: float
    limit_mm: float
    passed: bool
    time: float


def check_master(certified_mm: float, corrected_mm: float, limit_mm: float = 0.003
                 ) -> MasterCheck:
    """Pass when the corrected measurement of the master is within ``limit_mm``."""
    err = corrected_mm - certified_mm
    return MasterCheck(certified_mm, corrected_mm, err, limit_mm, abs(err) <= limit_mm,
                       time.time())
