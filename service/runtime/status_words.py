"""The status, fault and form words the CNC reads, from a snapshot of the gauge: pure, tested
bit by bit."""

from __future__ import annotations

from dataclasses import dataclass

from drivers.plc.registers import FaultBit, StatusBit, mm_to_units
from service.compensation import State


@dataclass(frozen=True)
class StatusSnapshot:
    """What the status and fault bits are made of, read at one moment."""

    healthy: bool = False
    camera_streaming: bool = False
    calibrated: bool = False
    latest_status: str | None = None      # None: nothing measured yet
    latest_in_tolerance: bool | None = None
    age_s: float | None = None            # of the latest measurement
    max_age_s: float = 5.0
    shadow: bool = True
    compensation: State = State.ACTIVE
    plc_configured: bool = False
    plc_connected: bool = False
    plc_outage: bool = False
    writes_blocked: bool = False
    rule_violation: bool = False          # SPC: a run rule fired at the latest subgroup
    study_failed: bool = False            # the type-1 gauge study failed or is overdue
    not_concentric: bool = False          # refused: off the spindle axis, no angle known
    tir_mm: float | None = None           # the run-out, when known
    runout_phase_deg: float | None = None
    max_tir_mm: float = 0.02
    ront_mm: float | None = None          # the roundness, when known
    lobes: int = 0


def status_words(s: StatusSnapshot) -> tuple[StatusBit, FaultBit, int]:
    """The ``status`` and ``faults`` registers and ``measurement_age`` (ms, 65535 when
    older or none) for a snapshot."""
    status, faults = StatusBit(0), FaultBit(0)
    if s.healthy:
        status |= StatusBit.HEALTHY
    if s.camera_streaming:
        status |= StatusBit.CAMERA_STREAMING
    else:
        faults |= FaultBit.CAMERA_LOST
    fresh = s.age_s is not None and s.age_s <= s.max_age_s
    if s.latest_status == "ok" and fresh:
        status |= StatusBit.MEASUREMENT_VALID
        if s.latest_in_tolerance:
            status |= StatusBit.IN_TOLERANCE
    elif s.latest_status is not None and s.latest_status != "ok":
        faults |= FaultBit.NO_MEASUREMENT
    if s.latest_status is not None and not fresh:
        faults |= FaultBit.STALE_MEASUREMENT
    if s.shadow:
        status |= StatusBit.SHADOW_MODE
    elif s.compensation in (State.ACTIVE, State.PENDING):
        status |= StatusBit.COMPENSATION_ACTIVE
    # The part just measured is out (flagged: the tool is still corrected), or a deviation
    # beyond the plausibility limit holds compensation with an alarm.
    if s.compensation is State.ALARM or (fresh and s.latest_status == "ok"
                                         and s.latest_in_tolerance is False):
        faults |= FaultBit.OUT_OF_TOLERANCE
    if s.compensation is State.STOPPED:
        faults |= FaultBit.SAFE_AREA_STOP
    if s.plc_configured:
        if s.plc_connected:
            status |= StatusBit.PLC_CONNECTED
        elif s.plc_outage:
            faults |= FaultBit.OFFSET_WRITE_FAILED
    if s.compensation is State.UNCERTAIN:  # an offset the CNC has not settled: nothing moves
        faults |= FaultBit.OFFSET_WRITE_FAILED
    if s.calibrated:
        status |= StatusBit.CALIBRATED
    else:
        faults |= FaultBit.NO_CALIBRATION
    if s.writes_blocked:
        faults |= FaultBit.MASTER_CHECK_DUE
    if s.rule_violation:
        status |= StatusBit.RULE_VIOLATION
    if s.study_failed:
        faults |= FaultBit.GAUGE_STUDY_FAILED
    if s.tir_mm is not None:
        status |= StatusBit.RUNOUT_KNOWN
        if s.tir_mm > s.max_tir_mm:
            faults |= FaultBit.RUNOUT_BEYOND_LIMIT
    if s.not_concentric:
        faults |= FaultBit.NOT_CONCENTRIC
    age_ms = 65535 if s.age_s is None else min(65535, int(s.age_s * 1000))
    return status, faults, age_ms


def form_words(s: StatusSnapshot) -> dict[str, int]:
    """The form and position registers for a snapshot (no value while not known)."""
    phase = s.runout_phase_deg
    return {"runout_tir": mm_to_units(s.tir_mm), "ront": mm_to_units(s.ront_mm),
            "runout_phase": 0xFFFF if phase is None or s.tir_mm is None
            else round(phase % 360.0 * 100.0) % 36000, "lobes": max(0, min(s.lobes, 0xFFFF))}
