"""Calibration sessions at the machine over HTTP: a thin layer over
``service.calibrate.session``. This module opens, lists, ends and activates sessions;
``session_steps`` feeds them images and runs their steps."""

from __future__ import annotations

import time

from fastapi import APIRouter, Depends, HTTPException

from service.api.auth import Caller, requires
from service.api.models import ActivateIn, SessionIn
from service.calibrate import commands
from service.calibrate.session import CalibrationSession, CalibrationSessions, SessionLimitError
from service.config import ApiSettings
from service.runtime.calibration import CalibrationContext
from service.runtime.compensating import CompensationService


def find(sessions: CalibrationSessions, sid: str) -> CalibrationSession:
    """The session ``sid``, or 404."""
    try:
        return sessions.get(sid)
    except KeyError:
        raise HTTPException(404, f"no calibration session {sid}") from None


def router(sessions: CalibrationSessions, context: CalibrationContext,
           comp: CompensationService, api: ApiSettings) -> APIRouter:
    """Sessions live in ``sessions``; activation goes through the calibration context and
    ends the offset hold the session's captures set (compensation)."""
    r = APIRouter(tags=["calibration sessions"])
    technician = Depends(requires(api, "technician"))

    @r.post("/calibration-sessions", status_code=201, summary="Start a calibration session")
    def start(body: SessionIn, caller: Caller = technician) -> dict:
        try:
            return sessions.create(body.board, body.note, str(caller)).as_dict()
        except commands.StepError as err:
            raise HTTPException(422, str(err)) from None
        except SessionLimitError as err:
            raise HTTPException(409, str(err)) from None

    @r.get("/calibration-sessions", summary="The kept sessions, newest first")
    def listing() -> dict:
        return {"items": [s.as_dict() for s in sessions.listing()],
                "max_open": sessions.max_open}

    @r.get("/calibration-sessions/{sid}", summary="A session: images, progress, results")
    def get(sid: str) -> dict:
        return find(sessions, sid).as_dict()

    @r.delete("/calibration-sessions/{sid}",
              summary="End a session: its images are deleted and its hold on offsets ends")
    def end(sid: str, _: Caller = technician) -> dict:
        find(sessions, sid)
        try:
            sessions.end(sid)
        except SessionLimitError as err:
            raise HTTPException(409, str(err)) from None
        comp.release_hold(sid)
        return {"ended": sid}

    @r.post("/calibration-sessions/{sid}/activate",
            summary="Import and activate the result (ends the hold its captures set)")
    async def activate(sid: str, body: ActivateIn, caller: Caller = technician) -> dict:
        s = find(sessions, sid)
        cal = s.calibration()
        if cal is None:
            raise HTTPException(409, "nothing to activate: " + (
                "the calibration was refused" if (s.report or {}).get("verdict") == "refused"
                else "run build first"))
        if context.store is None:
            raise HTTPException(503, f"the calibration store cannot be used: "
                                f"{context.store_error}")
        cid = context.store.add(cal, by=str(caller), note=body.note or s.note, quality=s.report,
                                activate=True)
        context.set_calibration(*context.store.get(cid))
        s.activated_id, s.touched = cid, time.time()
        s.save()
        # The technician is done with the board: its captures no longer hold offsets back (the
        # compensation still needs good measurements of a part near nominal to write any).
        comp.release_hold(sid)
        return s.as_dict()

    return r
