"""``create_app(gauge)``: the FastAPI application around a running gauge (tests inject one
built on simulated parts)."""

from __future__ import annotations

import contextlib
import sqlite3
from collections.abc import AsyncIterator
from pathlib import Path

from fastapi import APIRouter, Depends, FastAPI, Request
from fastapi.encoders import jsonable_encoder
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse, PlainTextResponse, RedirectResponse, Response
from fastapi.staticfiles import StaticFiles

from calib_store.store import NotStoredError
from service.api import (
    calibrations,
    compensation,
    export,
    jobs,
    master,
    measurements,
    quality,
    session_steps,
    sessions,
)
from service.api.auth import reader
from service.api.edge import SecurityHeaders
from service.api.limits import BodyLimit
from service.api.models import ERRORS
from service.plant.mqtt import gauge_identity
from service.runtime import Gauge

WEB = Path(__file__).resolve().parent.parent / "web"


def create_app(gauge: Gauge, manage_lifecycle: bool = True) -> FastAPI:
    """The application. With ``manage_lifecycle`` it starts and stops the gauge itself."""

    @contextlib.asynccontextmanager
    async def lifespan(_: FastAPI) -> AsyncIterator[None]:
        if manage_lifecycle:
            await gauge.start()
        try:
            yield
        finally:
            if manage_lifecycle:
                await gauge.stop()

    # Swagger UI and ReDoc load from a CDN that the gauge's own security policy blocks and an
    # offline shop cannot reach: /docs is the gauge's own page over /openapi.json.
    app = FastAPI(title="shaftgauge", version="0.1.0", lifespan=lifespan, docs_url=None,
                  redoc_url=None,
                  description="Lathe-side shaft diameter measurement. Reading is open on the "
                  "plant network; changes need an X-API-Key with a role.")

    # Outermost (added last): the Host check and the headers on every answer, 413s included.
    # Bodies are bounded before anything reads them, before routing and access checks.
    app.add_middleware(BodyLimit, default_bytes=gauge.settings.api.max_body_bytes,
                       larger=[(r"/api/v1/calibration-sessions/[^/]+/images/",
                                gauge.settings.api.max_image_bytes)])

    app.add_middleware(SecurityHeaders, trusted_hosts=gauge.settings.api.trusted_hosts)

    @app.exception_handler(RequestValidationError)
    async def validation_error(request: Request, exc: RequestValidationError) -> JSONResponse:
        # FastAPI reads a body that is not declared JSON as text, and says only that it is no
        # object: say what to send instead.
        content_type = request.headers.get("content-type", "")
        if "json" not in content_type and any(e["loc"][:1] == ("body",) for e in exc.errors()):
            return JSONResponse(status_code=415, content={"detail": (
                "the body must be JSON sent with Content-Type: application/json (it came "
                f"with {content_type or 'no Content-Type'})")})
        # FastAPI's default, but never echoing a request body back (it may hold a key).
        errors = [{k: v for k, v in e.items() if k != "input"} for e in exc.errors()]
        return JSONResponse(status_code=422, content={"detail": jsonable_encoder(errors)})

    @app.exception_handler(sqlite3.Error)
    @app.exception_handler(NotStoredError)
    async def not_stored(_: Request, exc: Exception) -> JSONResponse:
        # Every change is stored before it is in force (a transaction, or the runtime
        # settings written first): one that could not be stored changed nothing.
        text = str(exc) if isinstance(exc, NotStoredError) else \
            f"not stored, nothing changed: the store cannot be written ({exc})"
        return JSONResponse(status_code=503, content={"detail": text})

    api = APIRouter(prefix="/api/v1", dependencies=[Depends(reader(gauge.settings.api))],
                    responses=ERRORS)
    g, keys = gauge, gauge.settings.api
    api.include_router(measurements.router(g.feed, g.health, keys,
                                           {"spc": g.spc.events}))
    api.include_router(calibrations.router(g.context, keys))
    api.include_router(compensation.router(g.compensation, g.log, g.commands.run_command, keys,
                                           g.jobs, g.context.store_error))
    api.include_router(master.router(g.context, g.compensation, g.feed,
                                     g.settings.measurement, keys))
    api.include_router(sessions.router(g.sessions, g.context, g.compensation, keys))
    api.include_router(session_steps.router(g.sessions, g.compensation, g.pipeline, keys))
    api.include_router(quality.router(g.spc, g.studies, g.compensation, keys, g.jobs))
    api.include_router(jobs.router(g.jobs, keys))
    api.include_router(export.router(g.log, gauge_identity(g.settings.mqtt)[0],
                                     g.context.store_error, g.settings.spindle.max_tir_mm,
                                     g.jobs))

    @api.get("/status", tags=["system"], summary="Camera, PLC, pipeline, calibration, "
             "compensation")
    def status() -> dict:
        return g.health.status()

    app.include_router(api)

    @app.get("/healthz", tags=["system"], summary="The process is alive")
    def healthz() -> dict:
        return {"alive": True}

    @app.get("/readyz", tags=["system"],
             summary="Measuring and keeping what it decides: 200, otherwise 503 with reasons")
    def readyz() -> JSONResponse:
        ok = g.health.ready()
        return JSONResponse({"ready": ok, "problems": [p.as_dict()
                                                        for p in g.health.problems()]},
                            status_code=200 if ok else 503)

    @app.get("/metrics", tags=["system"], response_class=PlainTextResponse,
             dependencies=[Depends(reader(gauge.settings.api))])
    def metrics() -> Response:
        body, content_type = g.metrics.exposition()
        return Response(body, media_type=content_type)

    @app.get("/", include_in_schema=False)
    def root() -> RedirectResponse:
        return RedirectResponse("/ui/")

    @app.get("/docs", include_in_schema=False)
    def docs() -> RedirectResponse:
        return RedirectResponse("/ui/api-reference.html")

    app.mount("/ui", StaticFiles(directory=WEB, html=True), name="ui")
    return app
