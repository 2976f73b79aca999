"""Exports for the quality department: the archived measurements as a Q-DAS AQDEF file."""

from __future__ import annotations

import asyncio
import datetime as dt
import re
from typing import Annotated

from fastapi import APIRouter, HTTPException, Query
from fastapi.responses import Response

from calib_store.compensation_log import CompensationLog
from service.plant.aqdef import from_archive, from_parts
from service.runtime.jobs import JobService

MAX_ROWS = 1_000_000
Text = Annotated[str, Query(min_length=1, max_length=80, pattern=r"^[^\r\n\t]+$")]


def router(log: CompensationLog | None, gauge_id: str, store_error: str,
           max_tir_mm: float | None = None, jobs: JobService | None = None) -> APIRouter:
    """Reads the measurement archive (``store.archive_hz`` values a second are kept; the
    run-out's characteristic has ``max_tir_mm`` as its upper limit) and the part records."""
    r = APIRouter(tags=["export"])
    # The file name goes into a header (latin-1, quoted): the gauge id as a safe word.
    safe_id = re.sub(r"[^A-Za-z0-9._-]+", "_", gauge_id) or "gauge"

    @r.get("/export/aqdef", summary="Archived measurements as a Q-DAS ASCII transfer file",
           response_class=Response, responses={200: {"content": {"text/plain": {}}}})
    async def aqdef(
        from_: Annotated[dt.datetime | None, Query(alias="from", description=(
            "ISO 8601 (a time without a zone is UTC); default: the first kept"))] = None,
        to: Annotated[dt.datetime | None, Query(description="ISO 8601; default: now")] = None,
        part: Text = "shaft", characteristic: Text = "diameter",
    ) -> Response:
        if log is None:
            raise HTTPException(503, f"the measurement archive cannot be used: {store_error}")
        lo, hi = (None if t is None else (t if t.tzinfo else t.replace(tzinfo=dt.UTC))
                  .timestamp() for t in (from_, to))
        if lo is not None and hi is not None and lo > hi:
            raise HTTPException(422, f"from ({from_.isoformat()}) is after to "
                                f"({to.isoformat()})")
        rows = await asyncio.to_thread(log.measurements, lo, hi, MAX_ROWS)
        return dfq(from_archive(rows, gauge_id, part, characteristic, max_tir_mm))

    @r.get("/export/aqdef/parts", summary="A job's part records as a Q-DAS transfer file "
           "(a characteristic per feature)", response_class=Response,
           responses={200: {"content": {"text/plain": {}}}})
    async def aqdef_parts(
        job: Annotated[int | None, Query(ge=1, le=2**63 - 1, description=(
            "a stored job's id; default: the job in force"))] = None,
        limit: Annotated[int, Query(ge=1, le=100_000)] = 10_000,
    ) -> Response:
        if jobs is None or jobs.store is None:
            raise HTTPException(503, "the part records cannot be used: "
                                f"{jobs.store_error if jobs else store_error}")
        jid = job if job is not None else jobs.stored.id if jobs.stored else None
        if jid is None:
            raise HTTPException(409, "no stored job is in force: name one (?job=ID)")
        try:
            info = jobs.store.get(jid)
        except KeyError:
            raise HTTPException(404, f"no job {jid}") from None
        rows = await asyncio.to_thread(jobs.store.parts, limit, None, None, jid)
        return dfq(from_parts(rows[::-1], info.document, gauge_id))

    def dfq(text: str) -> Response:
        name = f"shaftgauge-{safe_id}-{dt.datetime.now(dt.UTC):%Y%m%dT%H%M%SZ}.dfq"
        return Response(text.encode("latin-1", "replace"),
                        media_type="text/plain; charset=iso-8859-1",
                        headers={"Content-Disposition": f'attachment; filename="{name}"',
                                 "X-Values": str(sum(1 for x in text.split("\r\n")
                                                     if x.startswith("K0001")))})
    return r
