"""Quality: the live SPC figures, and type-1 gauge studies run in the lathe."""

from __future__ import annotations

from fastapi import APIRouter, Depends, HTTPException, Query
from pydantic import Field

from service.api.auth import Caller, requires
from service.api.models import _Strict
from service.config import ApiSettings
from service.runtime.compensating import CompensationService
from service.runtime.job_service import JobService
from service.runtime.spc_service import SpcService
from service.runtime.studies import GaugeStudies, StudyError


class GaugeStudyIn(_Strict):
    """A type-1 study of the master in the lathe (lengths in mm)."""

    certified_mm: float = Field(gt=0, le=1000, description="the master's certified diameter")
    n: int = Field(50, ge=25, le=1000, description="values (each a fused measurement of new "
                   "frames)")
    tolerance_mm: float | None = Field(None, gt=0, le=100, description="the feature's "
                                       "tolerance T (USL - LSL); default: the feature's")
    feature: int | None = Field(None, ge=1, le=99, description="the job's feature the master "
                                "stands for (its tolerance is T); default: the single "
                                "feature's")


def router(spc: SpcService, studies: GaugeStudies, compensation: CompensationService,
           api: ApiSettings, jobs: JobService | None = None) -> APIRouter:
    """SPC reads; studies start with a technician key."""
    r = APIRouter(tags=["quality"])
    technician = Depends(requires(api, "technician"))

    @r.get("/spc", summary="Control limits, capability, run-rule violations of a feature "
           "(default: the one measured last)")
    def figures(feature: int | None = Query(None, ge=1, le=99)) -> dict:
        try:
            return spc.figures(feature)
        except KeyError as err:
            raise HTTPException(404, err.args[0]) from None

    @r.post("/spc/reset", summary="Start a new baseline for the control limits",
            dependencies=[technician])
    def reset() -> dict:
        spc.reset()
        return spc.figures()

    @r.get("/gauge-studies", summary="The running study's progress and the latest studies")
    def list_studies(limit: int = 20) -> dict:
        items = [] if studies.store is None else studies.store.list(min(max(limit, 1), 200))
        return {**studies.status(), "items": items}

    @r.post("/gauge-studies", status_code=202,
            summary="Measure the master n times (offsets held meanwhile) and compute Cg, Cgk")
    async def start(body: GaugeStudyIn, caller: Caller = technician) -> dict:
        f = compensation.feature()
        job = jobs.job if jobs is not None else None
        if body.feature is None and job is not None and len(job.features) > 1:
            raise HTTPException(422, f"feature: job {job.part_number!r} has "
                                f"{len(job.features)} features: name the one whose master "
                                f"is in the lathe (its features: "
                                f"{', '.join(str(x.number) for x in job.features)})")
        if body.feature is not None:
            try:
                if jobs is None or jobs.job is None:
                    raise KeyError("no job is in force")
                f = jobs.feature_of(jobs.job.feature(body.feature))
            except KeyError as err:
                raise HTTPException(422, f"feature: {err.args[0]}") from None
        tol = body.tolerance_mm or (f.tol_upper_mm - f.tol_lower_mm)
        try:
            sid = studies.start(body.certified_mm, body.n, tol, by=f"api:{caller}",
                                feature=body.feature)
        except StudyError as err:
            raise HTTPException(409, str(err)) from None
        return {"id": sid, "n": body.n, "certified_mm": body.certified_mm,
                "tolerance_mm": tol, "feature": body.feature}

    return r
