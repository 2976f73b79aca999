"""The offset exchange's arithmetic: what an offset does to the diameter, the step and
cumulative limits in the CNC's resolution, and what the CNC's registers say of an offset in
flight. Pure."""

from __future__ import annotations

import math

from service.compensation.records import CncReading, ControllerState
from service.compensation.settings import CompensationSettings


def limit_veto(s: CompensationSettings, p: ControllerState, total_mm: float | None
               ) -> tuple[str, str]:
    """(code, why) the pending offset must not be written with the CNC's total as read now,
    or ("", "")."""
    if total_mm is None:
        return "cnc_total_unreadable", ("the CNC's total wear offset cannot be read, so the "
                                        "cumulative limit cannot be checked")
    if p.baseline_mm is None:  # a reset or enabling came between the decision and now
        return "no_baseline", "the reference of the cumulative limit is being taken again"
    after = total_mm + (p.pending_offset_mm or 0.0) - p.baseline_mm
    if abs(after) > s.max_total_mm + 1e-9:
        return "limit", (f"the CNC's total would stand {after * 1000:+.1f} um from the "
                         f"baseline, beyond the limit of {s.max_total_mm * 1000:.0f} um")
    return "", ""


def effect_mm(s: CompensationSettings, offset_mm: float) -> float:
    """What an offset (offset units) does to the diameter, mm."""
    return offset_mm * s.offset_sign * (2.0 if s.programming == "radius" else 1.0)


def clip_step(s: CompensationSettings, wanted: float, cum_mm: float) -> tuple[float, bool]:
    """(step, limited): the offset ``wanted`` (offset units) clipped to ``max_step_mm``, and
    to ``max_total_mm`` around ``cum_mm``, in the CNC's resolution rounded toward zero; and
    whether the cumulative limit clipped it."""
    step = max(-s.max_step_mm, min(s.max_step_mm, wanted))
    target = max(-s.max_total_mm, min(s.max_total_mm, cum_mm + step))
    limited = abs(target - (cum_mm + step)) > 1e-12
    # In the CNC's resolution, rounded toward zero: what is logged is what is applied, and
    # rounding never takes the total past the limit.
    return toward_zero(target - cum_mm, s.offset_resolution_mm), limited


def cnc_verdict(p: ControllerState, cnc: CncReading) -> tuple[bool | None, str]:
    """Whether the CNC's registers say the pending offset was applied (True, False, or None
    while they cannot tell), and how they say it."""
    seq, step = p.pending_seq, p.pending_offset_mm or 0.0
    if cnc.ack_seq == seq:
        return True, "the CNC's acknowledgement register echoes its sequence"
    if p.pending_total_before_mm is not None and abs(step) > 0 and \
            abs(cnc.total_mm - (p.pending_total_before_mm + step)) < 0.5e-4:
        return True, "the CNC's total moved by the offset"
    if cnc.request_seq != seq:
        return False, (f"the CNC's request registers no longer hold it (they hold "
                       f"{cnc.request_seq}): cleared by the CNC or never received")
    return None, ""


def toward_zero(value_mm: float, resolution_mm: float) -> float:
    """``value_mm`` as a whole number of ``resolution_mm``, rounded toward zero (a hair of
    float error is forgiven: 0.30000000000000004 units is 0.3)."""
    units = value_mm / resolution_mm
    whole = math.floor(abs(units) + 1e-6)
    return math.copysign(whole * resolution_mm, units) if whole else 0.0


def same_total(a_mm: float, b_mm: float, s: CompensationSettings) -> bool:
    """Whether two readings of the CNC's total are the same (within half its resolution)."""
    return abs(a_mm - b_mm) < 0.5 * s.offset_resolution_mm
