"""Mastering: measure a master cylinder from the live camera, check it, set the correction."""

from __future__ import annotations

import asyncio
import uuid
from dataclasses import asdict

from fastapi import APIRouter, Depends, HTTPException
from pydantic import Field

from service.api.auth import Caller, requires
from service.api.models import _Strict
from service.calibrate.master import DiameterCorrection, check_master, correction_from_masters
from service.config import ApiSettings, MeasurementSettings
from service.measure.fuse import fuse
from service.measure.result import Measurement, Method, Status
from service.runtime.calibration import CalibrationContext
from service.runtime.compensating import CompensationService
from service.runtime.feed import MeasurementFeed


class MasterMeasureIn(_Strict):
    """Measure the master now in the lathe."""

    certified_mm: float = Field(gt=0, le=1000)
    frames: int = Field(10, ge=3, le=500)
    timeout_s: float = Field(30.0, gt=0, le=600)


class MasterPoint(_Strict):
    """A master's certificate and its raw (uncorrected) measurement."""

    certified_mm: float = Field(gt=0, le=1000)
    measured_mm: float = Field(gt=0, le=1000)


class CorrectionIn(_Strict):
    """One master (offset) or two (offset and scale)."""

    masters: list[MasterPoint] = Field(min_length=1, max_length=2)


def router(context: CalibrationContext, comp: CompensationService, feed: MeasurementFeed,
           ms: MeasurementSettings, api: ApiSettings) -> APIRouter:
    """Checks and corrections belong to the calibration context; measuring the master holds
    offsets (compensation) and reads the live feed."""
    r = APIRouter(tags=["master"])
    technician = Depends(requires(api, "technician"))

    @r.get("/master", summary="Correction in force, last master check, due or not")
    def master() -> dict:
        return context.master_status()

    @r.post("/master/measure", summary="Measure the master in the lathe and record a check")
    async def measure(body: MasterMeasureIn, caller: Caller = technician) -> dict:
        calibration_id = context.calibration_id
        if calibration_id is None or context.store is None:
            raise HTTPException(409, "no active calibration: activate one first")
        # The camera looks at the master, not at the part: no offset from what it measures.
        owner = f"master-{uuid.uuid4().hex[:8]}"
        comp.hold_offsets(body.timeout_s + 5.0, "the master is being measured", owner=owner,
                          code="master")
        q = feed.subscribers.add()
        raw, corrected = [], []
        try:
            async with asyncio.timeout(body.timeout_s):
                while len(raw) < body.frames:
                    rec = await q.get()
                    if rec.status == "ok" and rec.calibration_id == calibration_id:
                        raw.append(Measurement(Status.OK, Method(rec.method),
                                               rec.raw_diameter_mm, uncertainty_mm=None))
                        corrected.append(Measurement(Status.OK, Method(rec.method),
                                                     rec.diameter_mm, uncertainty_mm=None))
        except TimeoutError:
            raise HTTPException(504, f"only {len(raw)} good frames in {body.timeout_s:g} s: "
                                "is the master in view and the camera streaming?") from None
        finally:
            feed.subscribers.remove(q)
            comp.release_hold(owner)
        f_raw, f_cor = fuse(raw), fuse(corrected)
        check = check_master(body.certified_mm, f_cor.diameter_mm, ms.master_limit_mm)
        context.record_master_check(check.certified_mm, check.measured_mm, check.error_mm,
                                  check.limit_mm, check.passed, by=str(caller))
        return {"certified_mm": body.certified_mm, "raw_mm": f_raw.diameter_mm,
                "corrected_mm": f_cor.diameter_mm, "uncertainty_mm": f_cor.uncertainty_mm,
                "frames": f_cor.n_used, "check": asdict(check)}

    @r.post("/master/correction", summary="Set the diameter correction from masters")
    def correction(body: CorrectionIn, caller: Caller = technician) -> dict:
        calibration_id = context.calibration_id
        if calibration_id is None or context.store is None:
            raise HTTPException(409, "no active calibration: activate one first")
        try:
            corr = correction_from_masters([(m.certified_mm, m.measured_mm)
                                            for m in body.masters])
        except ValueError as err:
            raise HTTPException(422, str(err)) from None
        if abs(corr.offset_mm) > ms.max_correction_offset_mm or \
                abs(corr.scale - 1.0) > ms.max_correction_scale_error:
            raise HTTPException(422, f"correction refused: offset {corr.offset_mm * 1000:+.1f} um"
                                f", scale {corr.scale:.6f} (limits "
                                f"{ms.max_correction_offset_mm * 1000:.0f} um and "
                                f"{ms.max_correction_scale_error:g}, "
                                "measurement.max_correction_*): calibrate again, or check the "
                                "master's certificate")
        context.store.add_correction(calibration_id, corr.offset_mm, corr.scale,
                                     [m.model_dump() for m in body.masters],
                                     by=str(caller))
        context.set_correction(DiameterCorrection(corr.offset_mm, corr.scale, corr.created))
        return context.master_status()

    return r
