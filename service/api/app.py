"""``create_app(gauge)``: the FastAPI application around a running gauge (tests inject one
built on simulated parts)."""

from __future__ import annotations

import contextlib
from collections.abc import AsyncIterator
from pathlib import Path

from fastapi import APIRouter, Depends, FastAPI, Request
from fastapi.encoders import jsonable_encoder
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse, PlainTextResponse, RedirectResponse
from fastapi.staticfiles import StaticFiles

from service.api import calibrations, compensation, master, measurements, sessions
from service.api.auth import reader
from service.api.limits import BodyLimit
from service.api.models import ERRORS
from service.runtime import Gauge

WEB = Path(__file__).resolve().parent.parent / "web"


def metrics_text(gauge: Gauge) -> str:
    """Prometheus text exposition of the gauge's figures."""
    st = gauge.status()
    p = st["pipeline"]
    cam = st["camera"]["counters"]
    latest = gauge.latest
    lines: list[str] = []

    def metric(name: str, kind: str, help_: str, value: float | None, labels: str = "") -> None:
        if value is None:
            return
        lines.append(f"# HELP shaftgauge_{name} {help_}")
        lines.append(f"# TYPE shaftgauge_{name} {kind}")
        lines.append(f"shaftgauge_{name}{labels} {float(value):.9g}")

    metric("healthy", "gauge", "1 when camera, calibration and measurement are fine",
           int(st["healthy"]))
    metric("diameter_mm", "gauge", "Latest measured diameter",
           latest.diameter_mm if latest else None)
    metric("diameter_uncertainty_mm", "gauge", "Standard uncertainty of the latest diameter",
           latest.uncertainty_mm if latest else None)
    metric("measurement_rate_hz", "gauge", "Measurements per second (10 s)", p["rate_hz"])
    metric("frames_total", "counter", "Frames taken from the camera", p["frames_in"])
    metric("measurements_total", "counter", "Frames measured", p["measured"])
    metric("measurements_failed_total", "counter", "Frames without a diameter", p["failed"])
    metric("camera_frames_dropped_total", "counter", "Frames dropped for a slow consumer",
           cam["dropped"])
    metric("camera_frames_failed_total", "counter", "Incomplete frames", cam["failed"])
    metric("camera_missing_packets_total", "counter", "Missing GVSP packets",
           cam["missing_packets"])
    metric("camera_reconnects_total", "counter", "Camera reconnections", cam["reconnects"])
    metric("latency_median_ms", "gauge", "Frame to registers, median",
           p["latency"]["median_ms"])
    metric("latency_p99_ms", "gauge", "Frame to registers, 99th percentile",
           p["latency"]["p99_ms"])
    metric("cumulative_offset_mm", "gauge", "Acknowledged tool-wear offset since reset",
           st["compensation"]["cumulative_offset_mm"])
    metric("modbus_requests_total", "counter", "Modbus requests served",
           st["modbus"]["requests"])
    return "\n".join(lines) + "\n"


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

    app = FastAPI(title="shaftgauge", version="0.1.0", lifespan=lifespan,
                  description="Lathe-side shaft diameter measurement. Reading is open on the "
                  "plant network; changes need an X-API-Key with a role.")

    # Bodies are bounded before anything reads them, before routing and access checks.
    app.add_middleware(BodyLimit, default_bytes=gauge.settings.api.max_body_bytes,
                       larger=[(r"/api/v1/calibration-sessions/[^/]+/images/",
                                gauge.settings.api.max_image_bytes)])

    @app.exception_handler(RequestValidationError)
    async def validation_error(_: Request, exc: RequestValidationError) -> JSONResponse:
        # FastAPI's default, but never echoing a request body back (it may hold a key).
        errors = [{k: v for k, v in e.items() if k != "input"} for e in exc.errors()]
        return JSONResponse(status_code=422, content={"detail": jsonable_encoder(errors)})

    api = APIRouter(prefix="/api/v1", dependencies=[Depends(reader(gauge.settings.api))],
                    responses=ERRORS)
    api.include_router(measurements.router(gauge))
    api.include_router(calibrations.router(gauge))
    api.include_router(compensation.router(gauge))
    api.include_router(master.router(gauge))
    api.include_router(sessions.router(gauge))

    @api.get("/status", tags=["system"], summary="Camera, PLC, pipeline, calibration, "
             "compensation")
    def status() -> dict:
        return gauge.status()

    app.include_router(api)

    @app.get("/healthz", tags=["system"], summary="The process is alive")
    def healthz() -> dict:
        return {"alive": True}

    @app.get("/readyz", tags=["system"], summary="Measuring: 200, otherwise 503 with reasons")
    def readyz() -> JSONResponse:
        ok = gauge.healthy()
        return JSONResponse({"ready": ok, "problems": gauge.problems()},
                            status_code=200 if ok else 503)

    @app.get("/metrics", tags=["system"], response_class=PlainTextResponse,
             dependencies=[Depends(reader(gauge.settings.api))])
    def metrics() -> PlainTextResponse:
        return PlainTextResponse(metrics_text(gauge),
                                 media_type="text/plain; version=0.0.4")

    @app.get("/", include_in_schema=False)
    def root() -> RedirectResponse:
        return RedirectResponse("/ui/")

    app.mount("/ui", StaticFiles(directory=WEB, html=True), name="ui")
    return app
