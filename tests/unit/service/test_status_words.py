"""The status and fault bits the CNC reads: one row per bit, each a snapshot with the bit's
condition and the same snapshot without it."""

from __future__ import annotations

from dataclasses import replace

import pytest

from drivers.plc.registers import FaultBit, StatusBit
from service.compensation import State
from service.runtime.status_words import StatusSnapshot, status_words

# A gauge measuring in shadow mode with its PLC connected: the reference every row changes.
BASE = StatusSnapshot(healthy=True, camera_streaming=True, calibrated=True,
                      latest_status="ok", latest_in_tolerance=True, age_s=0.1, max_age_s=5.0,
                      shadow=True, compensation=State.ACTIVE, plc_configured=True,
                      plc_connected=True, plc_outage=False, writes_blocked=False)

ROWS = [
    # bit, the snapshot with it, the same without it
    (StatusBit.HEALTHY, {}, {"healthy": False}),
    (StatusBit.CAMERA_STREAMING, {}, {"camera_streaming": False}),
    (StatusBit.MEASUREMENT_VALID, {}, {"age_s": 6.0}),
    (StatusBit.MEASUREMENT_VALID, {}, {"latest_status": "no_stripe"}),
    (StatusBit.IN_TOLERANCE, {}, {"latest_in_tolerance": False}),
    (StatusBit.IN_TOLERANCE, {}, {"age_s": 6.0}),  # a stale diameter says nothing
    (StatusBit.COMPENSATION_ACTIVE, {"shadow": False}, {}),
    (StatusBit.COMPENSATION_ACTIVE, {"shadow": False},
     {"shadow": False, "compensation": State.UNCERTAIN}),
    (StatusBit.SHADOW_MODE, {}, {"shadow": False}),
    (StatusBit.PLC_CONNECTED, {}, {"plc_connected": False}),
    (StatusBit.CALIBRATED, {}, {"calibrated": False}),
    (FaultBit.CAMERA_LOST, {"camera_streaming": False}, {}),
    (FaultBit.NO_MEASUREMENT, {"latest_status": "fit_failed"}, {}),
    (FaultBit.OUT_OF_TOLERANCE, {"compensation": State.ALARM}, {}),
    (FaultBit.OUT_OF_TOLERANCE, {"latest_in_tolerance": False}, {}),  # flagged, corrected
    (FaultBit.SAFE_AREA_STOP, {"compensation": State.STOPPED}, {}),
    (FaultBit.OFFSET_WRITE_FAILED, {"plc_connected": False, "plc_outage": True},
     {"plc_connected": False}),
    (FaultBit.OFFSET_WRITE_FAILED, {"compensation": State.UNCERTAIN}, {}),
    (FaultBit.NO_CALIBRATION, {"calibrated": False}, {}),
    (FaultBit.STALE_MEASUREMENT, {"age_s": 5.5}, {"age_s": 4.5}),
    (FaultBit.STALE_MEASUREMENT, {"age_s": None}, {"latest_status": None, "age_s": None}),
    (FaultBit.MASTER_CHECK_DUE, {"writes_blocked": True}, {}),
    (StatusBit.RULE_VIOLATION, {"rule_violation": True}, {}),
    (FaultBit.GAUGE_STUDY_FAILED, {"study_failed": True}, {}),
    (StatusBit.RUNOUT_KNOWN, {"tir_mm": 0.004}, {}),
    (FaultBit.RUNOUT_BEYOND_LIMIT, {"tir_mm": 0.021, "max_tir_mm": 0.02},
     {"tir_mm": 0.019, "max_tir_mm": 0.02}),
    (FaultBit.NOT_CONCENTRIC, {"not_concentric": True}, {}),
]


def word(bit: StatusBit | FaultBit, s: StatusSnapshot) -> int:
    status, faults, _ = status_words(s)
    return int(status if isinstance(bit, StatusBit) else faults)


@pytest.mark.parametrize(("bit", "with_", "without"), ROWS,
                         ids=[f"{r[0].name.lower()}-{i}" for i, r in enumerate(ROWS)])
def test_each_bit_follows_its_condition(bit, with_, without) -> None:
    assert word(bit, replace(BASE, **with_)) & bit, (bit, with_)
    assert not word(bit, replace(BASE, **without)) & bit, (bit, without)


def test_every_bit_has_a_row() -> None:
    covered = {r[0] for r in ROWS}
    assert covered == set(StatusBit) | set(FaultBit)


def test_a_healthy_shadow_gauge_has_no_fault_and_a_fresh_age() -> None:
    status, faults, age_ms = status_words(BASE)
    assert faults == FaultBit(0) and age_ms == 100
    assert status == (StatusBit.HEALTHY | StatusBit.CAMERA_STREAMING | StatusBit.MEASUREMENT_VALID
                      | StatusBit.IN_TOLERANCE | StatusBit.SHADOW_MODE | StatusBit.PLC_CONNECTED
                      | StatusBit.CALIBRATED)
    assert status_words(replace(BASE, age_s=None))[2] == 65535
    assert status_words(replace(BASE, age_s=1e6))[2] == 65535


def test_the_form_registers_say_no_value_until_the_run_out_is_known() -> None:
    from drivers.plc.registers import NO_VALUE
    from service.runtime.status_words import form_words

    assert form_words(BASE) == {"runout_tir": NO_VALUE, "ront": NO_VALUE,
                                "runout_phase": 0xFFFF, "lobes": 0}
    known = replace(BASE, tir_mm=0.1005, runout_phase_deg=359.996, ront_mm=0.016, lobes=3)
    assert form_words(known) == {"runout_tir": 1005, "ront": 160, "runout_phase": 0,
                                 "lobes": 3}
    assert form_words(replace(known, runout_phase_deg=212.5))["runout_phase"] == 21250
