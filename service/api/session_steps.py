"""Images into a calibration session (uploaded, or captured from the live camera) and its
steps run in the background with their progress."""

from __future__ import annotations

import asyncio
import time

import numpy as np
from fastapi import APIRouter, Depends, HTTPException, Request

from service.api.auth import requires
from service.api.image_body import decode_image, image_size
from service.api.limits import check_image_size
from service.api.sessions import find
from service.calibrate import commands
from service.calibrate.session import (
    CalibrationSession,
    CalibrationSessions,
    ImageKind,
    SessionLimitError,
    Step,
)
from service.calibrate.worker import StepStoppedError
from service.config import ApiSettings
from service.runtime.compensating import CompensationService
from service.runtime.pipeline import FramePipeline

CAPTURE_TIMEOUT_S = 5.0
CAPTURE_HOLD_S = 600.0   # offsets held this long after the last capture
MAX_PIXELS = 8192 * 8192  # with no camera size known yet


def router(sessions: CalibrationSessions, comp: CompensationService, pipeline: FramePipeline,
           api: ApiSettings) -> APIRouter:
    """Captures read the pipeline's latest frame and hold offsets (compensation)."""
    r = APIRouter(tags=["calibration sessions"])
    technician = Depends(requires(api, "technician"))
    tasks: set[asyncio.Task] = set()

    async def store(s: CalibrationSession, kind: ImageKind, image: np.ndarray) -> dict:
        try:
            added = await asyncio.to_thread(s.add_image, kind, image, sessions.max_images)
        except SessionLimitError as err:
            raise HTTPException(409, str(err)) from None
        except OSError as err:
            raise HTTPException(507, str(err)) from None
        return {**added, **s.as_dict()}

    @r.post("/calibration-sessions/{sid}/images/{kind}", status_code=201,
            summary="Upload one image (PNG or JPEG body, grey or colour)")
    async def upload(sid: str, kind: ImageKind, request: Request, _: str = technician) -> dict:
        s = find(sessions, sid)
        data = await request.body()  # bounded by api.max_image_bytes before it is read
        if not data:
            raise HTTPException(422, "send one PNG or JPEG image as the request body")
        # The header is checked before a pixel is decoded: a small file can declare a
        # gigapixel image.
        check_image_size(image_size(data), pipeline.image_size(), MAX_PIXELS)
        image = await asyncio.to_thread(decode_image, data)
        if image is None:
            raise HTTPException(422, "the image could not be decoded (damaged data)")
        return await store(s, kind, image)

    @r.post("/calibration-sessions/{sid}/capture/{kind}", status_code=201,
            summary="Capture the next frame from the camera (offsets are held meanwhile)")
    async def capture(sid: str, kind: ImageKind, _: str = technician) -> dict:
        s = find(sessions, sid)
        # The camera now looks at a board, not a part: no offset from what it measures.
        comp.hold_offsets(CAPTURE_HOLD_S, f"calibration session {sid} is capturing", owner=sid)
        pipeline.read_whole_sensor(CAPTURE_HOLD_S)  # a region of interest is no calibration image
        asked = time.monotonic_ns()
        deadline = time.monotonic() + CAPTURE_TIMEOUT_S
        while True:  # a whole frame taken after the request, never one from before it
            frame = pipeline.latest_frame
            if frame is not None and frame.received_ns > asked and frame.origin is None:
                return await store(s, kind, frame.image)
            if time.monotonic() > deadline:
                raise HTTPException(409, "no new frame from the camera within "
                                    f"{CAPTURE_TIMEOUT_S:g} s: is it streaming?")
            await asyncio.sleep(0.02)

    async def background(s: CalibrationSession, step: Step) -> None:
        try:
            await asyncio.to_thread(sessions.run, s, step)
        except (commands.StepError, StepStoppedError):
            pass  # recorded in the session's progress, or the session is gone
        except Exception as err:  # a bug must show in the session, not kill the service
            s.progress = {"step": step, "state": "failed", "message": f"internal error: {err}"}

    @r.post("/calibration-sessions/{sid}/run/{step}", status_code=202,
            summary="Run one step in the background (poll the session for progress)")
    async def run(sid: str, step: Step, _: str = technician) -> dict:
        s = find(sessions, sid)
        if s.progress["state"] == "running":
            raise HTTPException(409, f"{s.progress['step']} is still running")
        s.progress = {"step": step, "state": "running", "message": f"{step}: queued"}
        task = asyncio.get_running_loop().create_task(background(s, step))
        tasks.add(task)
        task.add_done_callback(tasks.discard)
        return s.as_dict()

    return r
