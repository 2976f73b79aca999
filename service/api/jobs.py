"""Jobs (part programs: features and tools), the feature under the laser, part records."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Depends, HTTPException, Path, Query

from service.api.auth import Caller, requires
from service.api.models import FeatureSelectIn, JobIn
from service.compensation.job import JobError
from service.config import ApiSettings
from service.runtime.job_service import JobService

JobId = Annotated[int, Path(ge=1, le=2**63 - 1, description="job id")]


def router(jobs: JobService, api: ApiSettings) -> APIRouter:
    """Changes go through the job service (and from it to the store)."""
    r = APIRouter(tags=["jobs and parts"])
    technician = Depends(requires(api, "technician"))

    def stored():
        if jobs.store is None:
            raise HTTPException(503, f"the store cannot be used: {jobs.store_error}")
        return jobs.store

    @r.get("/jobs", summary="Every stored job version, newest first, and the one in force")
    def listing() -> dict:
        return {"items": [j.as_dict() for j in stored().list()], **jobs.status()}

    @r.get("/jobs/audit", summary="Who added and activated which job")
    def audit(limit: int = Query(100, ge=1, le=1000)) -> dict:
        return {"items": stored().audit(limit)}

    @r.get("/jobs/{jid}", summary="One job version with its document")
    def get(jid: JobId) -> dict:
        try:
            return stored().get(jid).as_dict()
        except KeyError:
            raise HTTPException(404, f"no job {jid}") from None

    @r.post("/jobs", status_code=201, summary="Add a job as its part number's next version")
    async def add(body: JobIn, caller: Caller = technician) -> dict:
        stored()
        try:
            return (await jobs.add(body.document, str(caller), body.note, body.activate)
                    ).as_dict()
        except JobError as err:
            raise HTTPException(422, f"document: {err}") from None

    @r.post("/jobs/{jid}/activate", summary="Put a stored job in force")
    async def activate(jid: JobId, caller: Caller = technician) -> dict:
        stored()
        try:
            return (await jobs.activate(jid, str(caller))).as_dict()
        except KeyError:
            raise HTTPException(404, f"no job {jid}") from None
        except (JobError, ValueError) as err:  # fits no more with today's settings
            raise HTTPException(409, f"job {jid} cannot be put in force: {err}") from None

    @r.delete("/jobs/active", summary="No stored job: the single feature of the settings")
    def deactivate(caller: Caller = technician) -> dict:
        jobs.deactivate(str(caller))
        return jobs.status()

    @r.put("/jobs/feature", summary="The feature under the laser (null: recognised)")
    def select(body: FeatureSelectIn, _: Caller = technician) -> dict:
        try:
            jobs.select(body.feature)
        except KeyError as err:
            raise HTTPException(422, f"feature: {err.args[0]}") from None
        return jobs.status()

    @r.get("/parts", summary="Part records, newest first")
    def parts(limit: int = Query(100, ge=1, le=5000),
              before_id: int | None = Query(None, ge=1, le=2**63 - 1),
              serial: str | None = Query(None, max_length=200)) -> dict:
        if jobs.store is None:  # no store: the parts of this run
            return {"items": list(jobs.part_log.recent)[:limit], "stored": False}
        items = jobs.store.parts(limit, before_id, serial)
        return {"items": items, "stored": True,
                "next_before_id": items[-1]["id"] if len(items) == limit else None}

    return r
