"""Where a measured part stands among the bands of ``CompensationSettings``: within the
tolerance, out of it (flagged, still corrected), beyond the plausibility limit (held with an
alarm) or beyond the safe area (stopped). Pure."""

from __future__ import annotations

import enum

from service.compensation.settings import CompensationSettings


class PartBand(enum.StrEnum):
    """A measured deviation from nominal, judged."""

    IN_TOLERANCE = "in_tolerance"
    OUT_OF_TOLERANCE = "out_of_tolerance"   # flagged; the tool is still corrected
    IMPLAUSIBLE = "implausible"             # nothing written, an alarm until plausible again
    BEYOND_SAFE_AREA = "beyond_safe_area"   # stopped until a person resets


def part_band(s: CompensationSettings, deviation_mm: float) -> PartBand:
    """The band of a measured deviation from nominal (mm of diameter)."""
    if abs(deviation_mm) > s.safe_area_mm:
        return PartBand.BEYOND_SAFE_AREA
    if abs(deviation_mm) > s.plausibility():
        return PartBand.IMPLAUSIBLE
    if not s.tol_lower_mm <= deviation_mm <= s.tol_upper_mm:
        return PartBand.OUT_OF_TOLERANCE
    return PartBand.IN_TOLERANCE


def tolerance_text(s: CompensationSettings) -> str:
    """The tolerance as an operator reads it (um)."""
    return f"{s.tol_lower_mm * 1000:+.1f}/{s.tol_upper_mm * 1000:+.1f} um"
