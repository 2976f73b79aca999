"""Exports for the quality department: the archived measurements as a Q-DAS AQDEF file."""

from __future__ import annotations

import asyncio
import datetime as dt
import re
from collections.abc import AsyncIterator
from typing import Annotated

from fastapi import APIRouter, HTTPException, Query
from fastapi.responses import Response, StreamingResponse

from calib_store.compensation_log import CompensationLog
from service.plant.aqdef import (
    archive_part,
    archive_values,
    as_text,
    encoded,
    from_parts,
    header_lines,
    value_lines,
)
from service.runtime.job_service import JobService

MAX_ROWS = 1_000_000
"""The most archived rows one request takes (11.6 days at the default 1 a second): a longer
span is asked for in parts (``from``, ``to``)."""
EXPORTS_AT_ONCE = 1
"""Archive exports streamed at once; another is refused (429) meanwhile: each formats on a
core of its own, and the gauge measures on the same two."""
PAGE_ROWS = 5_000
"""Rows read and formatted at a time, off the event loop: memory is a page's, and the loop
(the CNC's Modbus link shares it) never waits on an export."""
Text = Annotated[str, Query(min_length=1, max_length=80, pattern=r"^[^\r\n\t]+$")]


def router(log: CompensationLog | None, gauge_id: str, store_error: str,
           max_tir_mm: float | None = None, jobs: JobService | None = None) -> APIRouter:
    """Reads the measurement archive (``store.archive_hz`` values a second are kept; the
    run-out's characteristic has ``max_tir_mm`` as its upper limit) and the part records."""
    r = APIRouter(tags=["export"])
    running = asyncio.Semaphore(EXPORTS_AT_ONCE)
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
        if running.locked():
            raise HTTPException(429, f"{EXPORTS_AT_ONCE} export of the archive is running: "
                                "ask again when it is done", headers={"Retry-After": "10"})
        await running.acquire()
        try:
            summary = await asyncio.to_thread(log.measurement_summary, lo, hi, MAX_ROWS)
        except BaseException:
            running.release()
            raise
        header = archive_part(summary, gauge_id, part, characteristic, max_tir_mm)
        pages = log.measurement_pages(lo, hi, MAX_ROWS, PAGE_ROWS, summary["last_seq"])

        async def body() -> AsyncIterator[bytes]:
            try:
                yield await asyncio.to_thread(_encoded, header_lines(header))
                while (rows := await asyncio.to_thread(next, pages, None)) is not None:
                    yield await asyncio.to_thread(
                        lambda r=rows: _encoded(value_lines(header, archive_values(header, r))))
            finally:
                running.release()

        return StreamingResponse(body(), media_type=DFQ_TYPE,
                                 headers={**attachment(), "X-Values": str(summary["good"])})

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

    def attachment() -> dict[str, str]:
        name = f"shaftgauge-{safe_id}-{dt.datetime.now(dt.UTC):%Y%m%dT%H%M%SZ}.dfq"
        return {"Content-Disposition": f'attachment; filename="{name}"'}

    def dfq(text: str) -> Response:
        return Response(encoded(text), media_type=DFQ_TYPE,
                        headers={**attachment(),
                                 "X-Values": str(sum(1 for x in text.split("\r\n")
                                                     if x.startswith("K0001")))})
    return r


DFQ_TYPE = "text/plain; charset=windows-1252"


def _encoded(lines: list[str]) -> bytes:
    return encoded(as_text(lines))
