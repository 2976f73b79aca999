"""Calibration sessions at the machine: collect images (upload or capture from the live
camera), run each step in the background with its progress, review the report, activate."""

from __future__ import annotations

import asyncio
import shutil
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import cv2
import numpy as np
from fastapi import APIRouter, Depends, HTTPException, Request
from pydantic import Field

from calib_store.model import Calibration
from service.api.auth import requires
from service.api.limits import check_image_size, png_size
from service.api.models import _Strict
from service.calibrate import commands
from service.runtime import Gauge

Kind = Literal["view", "plane_off", "plane_on", "axis"]
Step = Literal["intrinsics", "plane", "axis", "build"]
MAX_PIXELS = 8192 * 8192  # with no camera size known yet
CAPTURE_TIMEOUT_S = 5.0
CAPTURE_HOLD_S = 600.0   # offsets held this long after the last capture


class SessionIn(_Strict):
    """A new session."""

    board: str = Field("11x8x8", description="COLSxROWSxMM: inner corners and square size")
    note: str = Field("", max_length=2000)


class ActivateIn(_Strict):
    """Import the built calibration and measure with it."""

    note: str = Field("", max_length=2000)


@dataclass
class Session:
    """One calibration session's images and results."""

    id: str
    board: str
    note: str
    by: str
    dir: Path
    created: float = field(default_factory=time.time)
    touched: float = field(default_factory=time.monotonic)
    images: dict[str, list[str]] = field(default_factory=lambda: {
        "view": [], "plane_off": [], "plane_on": [], "axis": []})
    results: dict[str, Any] = field(default_factory=dict)
    progress: dict[str, Any] = field(default_factory=lambda: {"step": None, "state": "idle",
                                                              "message": ""})
    calibration: Calibration | None = None
    report: dict[str, Any] | None = None
    activated_id: int | None = None

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready view."""
        return {"id": self.id, "board": self.board, "note": self.note, "by": self.by,
                "created": self.created,
                "images": {k: len(v) for k, v in self.images.items()},
                "results": self.results, "progress": self.progress, "report": self.report,
                "built": self.calibration is not None, "activated_id": self.activated_id}


def router(gauge: Gauge) -> APIRouter:
    r = APIRouter(tags=["calibration sessions"])
    technician = Depends(requires(gauge.settings.api, "technician"))
    sessions: dict[str, Session] = {}
    root = gauge.settings.store.path.parent / "calibration-sessions"
    tasks: set[asyncio.Task] = set()

    api = gauge.settings.api

    def expire() -> None:
        """Delete sessions untouched for ``api.session_expiry_h`` (not while a step runs)."""
        now = time.monotonic()
        for sid, s in list(sessions.items()):
            if now - s.touched > api.session_expiry_h * 3600.0 and \
                    s.progress["state"] != "running":
                del sessions[sid]
                shutil.rmtree(s.dir, ignore_errors=True)

    def find(sid: str) -> Session:
        expire()
        if sid not in sessions:
            raise HTTPException(404, f"no calibration session {sid}")
        sessions[sid].touched = time.monotonic()
        return sessions[sid]

    def room_for_image(s: Session) -> None:
        held = sum(len(v) for v in s.images.values())
        if held >= api.max_session_images:
            raise HTTPException(409, f"session {s.id} holds {held} images, the most one "
                                f"session may (api.max_session_images)")

    async def save(s: Session, kind: Kind, image: np.ndarray) -> dict[str, Any]:
        room_for_image(s)
        h, w = image.shape[:2]
        path = s.dir / f"{kind}_{len(s.images[kind]):03d}.png"
        s.images[kind].append(str(path))  # the slot is taken before the write yields
        if not await asyncio.to_thread(cv2.imwrite, str(path), image):
            s.images[kind].remove(str(path))
            raise HTTPException(507, "could not store the image (is the disk full?)")
        return {"kind": kind, "index": len(s.images[kind]) - 1, "size": [w, h],
                **s.as_dict()}

    def camera_size() -> tuple[int, int] | None:
        """(width, height) of the camera's images: the latest frame's, else the active
        calibration's."""
        frame = gauge.latest_frame
        if frame is not None:
            return frame.image.shape[1], frame.image.shape[0]
        if gauge.calibration is not None:
            w, h = gauge.calibration[1].image_size
            return int(w), int(h)
        return None

    @r.post("/calibration-sessions", status_code=201, summary="Start a calibration session")
    def start(body: SessionIn, role: str = technician) -> dict:
        try:
            commands.parse_board(body.board)
        except commands.StepError as err:
            raise HTTPException(422, str(err)) from None
        expire()
        if len(sessions) >= api.max_calibration_sessions:
            raise HTTPException(409, f"{len(sessions)} calibration sessions are open, the most "
                                "allowed (api.max_calibration_sessions); finish one, or wait "
                                f"for it to expire after {api.session_expiry_h:g} h")
        sid = uuid.uuid4().hex[:12]
        d = root / sid
        d.mkdir(parents=True, exist_ok=True)
        sessions[sid] = Session(sid, body.board, body.note, role, d)
        return sessions[sid].as_dict()

    @r.get("/calibration-sessions/{sid}", summary="A session: images, progress, results")
    def get(sid: str) -> dict:
        return find(sid).as_dict()

    @r.post("/calibration-sessions/{sid}/images/{kind}", status_code=201,
            summary="Upload one image (PNG body)")
    async def upload(sid: str, kind: Kind, request: Request, _: str = technician) -> dict:
        s = find(sid)
        room_for_image(s)
        data = await request.body()  # bounded by api.max_image_bytes before it is read
        if not data:
            raise HTTPException(422, "send one PNG image as the request body")
        # The header is checked before a pixel is decoded: a small file can declare a
        # gigapixel image.
        check_image_size(png_size(data), camera_size(), MAX_PIXELS)
        image = await asyncio.to_thread(_decode_gray, data)
        if image is None:
            raise HTTPException(422, "the PNG could not be decoded (damaged data)")
        return await save(s, kind, image)

    @r.post("/calibration-sessions/{sid}/capture/{kind}", status_code=201,
            summary="Capture the next frame from the camera (offsets are held meanwhile)")
    async def capture(sid: str, kind: Kind, _: str = technician) -> dict:
        s = find(sid)
        # The camera now looks at a board, not a part: no offset from what it measures.
        gauge.hold_offsets(CAPTURE_HOLD_S, f"calibration session {sid} is capturing",
                           owner=sid)
        asked = time.monotonic_ns()
        deadline = time.monotonic() + CAPTURE_TIMEOUT_S
        while True:  # a frame taken after the request, never one from before it
            frame = gauge.latest_frame
            if frame is not None and frame.received_ns > asked:
                return await save(s, kind, frame.image)
            if time.monotonic() > deadline:
                raise HTTPException(409, "no new frame from the camera within "
                                    f"{CAPTURE_TIMEOUT_S:g} s: " + "; ".join(gauge.problems()))
            await asyncio.sleep(0.02)

    def run_step(s: Session, step: Step) -> dict[str, Any]:
        d, board = s.dir, commands.parse_board(s.board)
        if step == "intrinsics":
            # Every image with the board in it constrains the intrinsics (the principal point
            # most of all: tests/bench/principal_point.py), not only the views.
            result, _ = commands.intrinsics_step(
                s.images["view"] + s.images["plane_off"] + s.images["axis"], board)
        elif step == "plane":
            pairs = [p for pair in zip(s.images["plane_off"], s.images["plane_on"],
                                       strict=False) for p in pair]
            if len(s.images["plane_off"]) != len(s.images["plane_on"]):
                raise commands.StepError("plane images come in pairs: as many laser-on as "
                                         "laser-off images")
            result, _ = commands.plane_step(str(d / "intrinsics.json"), pairs)
        elif step == "axis":
            plane = d / "plane.json"
            result, _ = commands.axis_step(str(d / "intrinsics.json"),
                                           str(plane) if plane.exists() else None,
                                           s.images["axis"])
        else:
            cal, report = commands.build_step(str(d / "intrinsics.json"), str(d / "plane.json"),
                                              str(d / "axis.json"))
            s.calibration, s.report = cal, report.as_dict()
            return {"step": "build", "ok": cal is not None, "verdict": report.verdict,
                    "reason": "; ".join(report.reasons)}
        commands.write_json(str(d / f"{step}.json"), result)
        return result

    async def background(s: Session, step: Step) -> None:
        s.progress = {"step": step, "state": "running", "message": f"{step}: working",
                      "started": time.time()}
        try:
            result = await asyncio.to_thread(run_step, s, step)
            s.results[step] = {k: v for k, v in result.items() if k != "report"}
            ok = result.get("ok", False)
            s.progress = {"step": step, "state": "done" if ok else "failed",
                          "message": result.get("reason") or f"{step}: done",
                          "finished": time.time()}
        except commands.StepError as err:
            s.progress = {"step": step, "state": "failed", "message": str(err)}
        except Exception as err:  # a bug must show in the session, not kill the service
            s.progress = {"step": step, "state": "failed", "message": f"internal error: {err}"}

    @r.post("/calibration-sessions/{sid}/run/{step}", status_code=202,
            summary="Run one step in the background (poll the session for progress)")
    async def run(sid: str, step: Step, _: str = technician) -> dict:
        s = find(sid)
        if s.progress["state"] == "running":
            raise HTTPException(409, f"{s.progress['step']} is still running")
        task = asyncio.get_running_loop().create_task(background(s, step))
        tasks.add(task)
        task.add_done_callback(tasks.discard)
        await asyncio.sleep(0)
        return s.as_dict()

    @r.post("/calibration-sessions/{sid}/activate",
            summary="Import and activate the result (ends the hold its captures set)")
    async def activate(sid: str, body: ActivateIn, role: str = technician) -> dict:
        s = find(sid)
        if s.calibration is None:
            verdict = (s.report or {}).get("verdict")
            raise HTTPException(409, "nothing to activate: " + (
                "the calibration was refused" if verdict == "refused" else "run build first"))
        if gauge.store is None:
            raise HTTPException(503, f"the calibration store cannot be used: "
                                f"{gauge.store_error}")
        cid = gauge.store.add(s.calibration, by=role, note=body.note or s.note,
                              quality=s.report, activate=True)
        gauge.set_calibration(*gauge.store.get(cid))
        s.activated_id = cid
        # The technician is done with the board: its captures no longer hold offsets back (the
        # compensation still needs good measurements of a part near nominal to write any).
        gauge.release_hold(sid)
        return s.as_dict()

    return r


def _decode_gray(data: bytes) -> np.ndarray | None:
    """A PNG's pixels as one grey channel (None when damaged)."""
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if image is not None and image.ndim == 3:
        image = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    return image
