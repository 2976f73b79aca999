"""Calibrations: list, get, import, export, activate."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Depends, HTTPException, Path
from fastapi.responses import JSONResponse

from calib_store.model import CalibrationError, parse_calibration
from calib_store.store import StoreError
from service.api.auth import Caller, requires
from service.api.models import CalibrationImportIn
from service.config import ApiSettings
from service.runtime.calibration import CalibrationContext

# SQLite integers are 64-bit: a larger id is a malformed request, not a server error.
CalibrationId = Annotated[int, Path(ge=1, le=2**63 - 1, description="calibration id")]


def router(context: CalibrationContext, api: ApiSettings) -> APIRouter:
    """Reads the store; activates through the calibration context."""
    r = APIRouter(tags=["calibrations"])
    technician = Depends(requires(api, "technician"))

    def store():
        if context.store is None:
            raise HTTPException(503, "the calibration store cannot be used: "
                                f"{context.store_error}")
        return context.store

    def find(cid: int):
        try:
            return store().get(cid)
        except KeyError:
            raise HTTPException(404, f"no calibration {cid}") from None
        except StoreError as err:
            raise HTTPException(409, str(err)) from None

    @r.get("/calibrations", summary="Every calibration version, newest first")
    def list_all() -> dict:
        return {"items": [i.as_dict() for i in store().list()]}

    @r.get("/calibrations/audit", summary="Audit log of calibration changes")
    def audit(limit: int = 100) -> dict:
        return {"items": store().audit(min(max(limit, 1), 1000))}

    @r.get("/calibrations/{cid}", summary="One calibration with its document")
    def get(cid: CalibrationId) -> dict:
        info, cal = find(cid)
        return {**info.as_dict(), "document": cal.to_document()}

    @r.get("/calibrations/{cid}/export", summary="The interchange document, as a file")
    def export(cid: CalibrationId) -> JSONResponse:
        _, cal = find(cid)
        return JSONResponse(cal.to_document(), headers={
            "Content-Disposition": f'attachment; filename="calibration-{cid}.json"'})

    @r.post("/calibrations", status_code=201, summary="Import a calibration document")
    async def import_(body: CalibrationImportIn, caller: Caller = technician) -> dict:
        try:
            cal = parse_calibration(body.document)
        except CalibrationError as err:
            raise HTTPException(422, f"document: {err}") from None
        cid = store().add(cal, by=str(caller), note=body.note, activate=body.activate)
        if body.activate:
            context.set_calibration(*store().get(cid))
        info, _ = store().get(cid)
        return info.as_dict()

    @r.post("/calibrations/{cid}/activate", summary="Measure with this calibration")
    async def activate(cid: CalibrationId, caller: Caller = technician) -> dict:
        find(cid)
        try:
            store().activate(cid, by=str(caller))
        except StoreError as err:
            raise HTTPException(409, str(err)) from None
        info, cal = store().get(cid)
        context.set_calibration(info, cal)
        return info.as_dict()

    return r
