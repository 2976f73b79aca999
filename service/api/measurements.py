"""Latest measurement, history, and the live stream (Server-Sent Events)."""

from __future__ import annotations

import asyncio
import json
from collections.abc import AsyncIterator

import cv2
from fastapi import APIRouter, HTTPException, Query, Request
from fastapi.responses import Response, StreamingResponse

from service.config import ApiSettings
from service.measure.overlay import draw_overlay, on_sensor
from service.runtime.feed import MeasurementFeed, Subscribers
from service.runtime.health import HealthReport

SSE_KEEPALIVE_S = 10.0


def _event(kind: str, data: dict) -> str:
    return f"event: {kind}\ndata: {json.dumps(data)}\n\n"


def _why(health: HealthReport) -> str:
    return "; ".join(p.text for p in health.problems())


def router(feed: MeasurementFeed, health: HealthReport, api: ApiSettings,
           more_events: dict[str, Subscribers] | None = None) -> APIRouter:
    """Reads the feed; says why there is nothing from the health report. The live stream
    carries measurements, decisions and ``more_events`` (kind -> source)."""
    r = APIRouter(tags=["measurements"])
    sources = {"measurement": feed.subscribers, "decision": feed.decisions,
               **(more_events or {})}
    open_streams = 0  # changed on the event loop only

    @r.get("/measurements/latest", summary="The latest measurement")
    def latest() -> dict:
        if feed.latest is None:
            raise HTTPException(404, "no measurement yet: " + _why(health))
        return {**feed.latest.as_dict(), "age_s": feed.measurement_age_s()}

    @r.get("/frame/latest.jpg", summary="The latest measured frame, stripe and fitted section "
           "drawn over it", response_class=Response,
           responses={200: {"content": {"image/jpeg": {}}}})
    def latest_frame(width: int = Query(688, ge=64, le=4096, description="picture width, px"),
                     overlay: bool = Query(True, description="draw stripe and section")
                     ) -> Response:
        measured = feed.latest_measured
        if measured is None:
            raise HTTPException(404, "no measured frame yet: " + _why(health))
        frame, m, geometry = measured
        # A region of interest is shown where it lies on the sensor.
        image = on_sensor(frame.image, frame.origin, geometry.image_size)
        picture = draw_overlay(image, m if overlay else None, geometry,
                               min(width, image.shape[1]))
        ok, jpg = cv2.imencode(".jpg", picture, [cv2.IMWRITE_JPEG_QUALITY, 85])
        if not ok:
            raise HTTPException(500, "could not encode the frame")
        return Response(jpg.tobytes(), media_type="image/jpeg",
                        headers={"Cache-Control": "no-store",
                                 "X-Frame-Id": str(frame.frame_id)})

    @r.get("/measurements", summary="History, newest first")
    def history(
        since: float | None = Query(None, description="from this Unix time (s)"),
        until: float | None = Query(None, description="up to this Unix time (s)"),
        before_seq: int | None = Query(None, ge=0, description="page: older than this seq"),
        limit: int = Query(100, ge=1, le=5000),
        ok_only: bool = Query(False, description="only measurements with status ok"),
    ) -> dict:
        if since is not None and until is not None and since > until:
            raise HTTPException(422, "since must not be after until")
        out = []
        for rec in feed.history_newest_first():
            if before_seq is not None and rec.seq >= before_seq:
                continue
            if until is not None and rec.time > until:
                continue
            if since is not None and rec.time < since:
                break
            if ok_only and rec.status != "ok":
                continue
            out.append(rec.as_dict())
            if len(out) >= limit:
                break
        return {"items": out, "next_before_seq": out[-1]["seq"] if len(out) == limit
                else None}

    @r.get("/stream", summary="Live measurements and compensation decisions (SSE)")
    async def stream(request: Request) -> StreamingResponse:
        nonlocal open_streams
        cap = api.max_streams
        if open_streams >= cap:
            raise HTTPException(503, f"{open_streams} live streams are open, the most this "
                                "service serves (api.max_streams); poll "
                                "/api/v1/measurements/latest instead", headers={
                                    "Retry-After": "10"})
        open_streams += 1

        async def events() -> AsyncIterator[str]:
            nonlocal open_streams
            queues = {kind: src.add() for kind, src in sources.items()}
            closing = asyncio.ensure_future(feed.closing.wait())
            try:
                yield "retry: 2000\n\n"
                if feed.latest is not None:
                    yield _event("measurement", feed.latest.as_dict())
                while not await request.is_disconnected() and not feed.closing.is_set():
                    gets = {asyncio.ensure_future(q.get()): kind for kind, q in queues.items()}
                    done, pending = await asyncio.wait({*gets, closing},
                                                       timeout=SSE_KEEPALIVE_S,
                                                       return_when=asyncio.FIRST_COMPLETED)
                    for p in pending - {closing}:
                        p.cancel()
                    if not done:
                        yield ": keep-alive\n\n"
                    for fut, kind in gets.items():  # in the sources' order
                        if fut in done:
                            item = fut.result()
                            yield _event(kind, item.as_dict() if hasattr(item, "as_dict")
                                         else item)
            finally:
                closing.cancel()
                open_streams -= 1
                for kind, q in queues.items():
                    sources[kind].remove(q)

        return StreamingResponse(events(), media_type="text/event-stream",
                                 headers={"Cache-Control": "no-cache",
                                          "X-Accel-Buffering": "no"})

    return r
