"""The feature (nominal, tolerance), compensation settings, shadow mode, commands, offset log,
and the part temperature."""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from dataclasses import asdict, replace

from fastapi import APIRouter, Depends, HTTPException, Query

from calib_store.compensation_log import CompensationLog
from drivers.plc.registers import Command
from service.api.auth import Caller, requires
from service.api.models import CommandIn, CompensationIn, FeatureIn, ShadowIn, TemperatureIn
from service.compensation import CompensationSettings, Decision, Kind
from service.config import ApiSettings
from service.runtime.compensating import CompensationService
from service.runtime.job_service import JobService

RunCommand = Callable[..., Awaitable[Decision | None]]


def router(comp: CompensationService, log: CompensationLog | None, run_command: RunCommand,
           api: ApiSettings, jobs: JobService, store_error: str = "") -> APIRouter:
    """Changes go through the compensation service (``run_command`` also acknowledges the
    command in the registers); the decision log is read from the store; the feature is the
    job's, through its owner (``JobService``)."""
    r = APIRouter(tags=["compensation"])
    technician = Depends(requires(api, "technician"))
    admin = Depends(requires(api, "admin"))

    # The endpoints that change the controller are async: they run on the event loop, in turn
    # with the compensation task and the CNC's register writes, never beside them in a thread.
    async def apply(settings: CompensationSettings, caller: Caller) -> dict:
        try:
            d = await comp.update_settings(settings, who=f"api:{caller}")
        except ValueError as err:
            raise HTTPException(422, str(err)) from None
        return {"settings": asdict(comp.settings), "decision": d.as_dict()}

    @r.get("/feature", summary="Nominal diameter and tolerance of the current feature")
    def feature() -> dict:
        f = jobs.feature_in_view()  # the job's: named, measured last, or its first
        return {"nominal_mm": f.nominal_mm, "tol_upper_mm": f.tol_upper_mm,
                "tol_lower_mm": f.tol_lower_mm}

    @r.put("/feature", summary="Set the feature directly: a job of one feature (technician)")
    async def set_feature(body: FeatureIn, caller: Caller = technician) -> dict:
        try:
            d = await jobs.set_feature(f"api:{caller}", **body.model_dump())
        except ValueError as err:
            raise HTTPException(422, str(err)) from None
        return {"settings": asdict(comp.settings), "decision": d.as_dict()}

    @r.get("/compensation", summary="Compensation settings and state")
    def compensation() -> dict:
        return {"settings": asdict(comp.settings), **comp.status()}

    @r.put("/compensation", summary="Tune compensation (admin)")
    async def tune(body: CompensationIn, caller: Caller = admin) -> dict:
        changes = {k: v for k, v in body.model_dump().items() if v is not None}
        return await apply(replace(comp.settings, **changes), caller)

    @r.put("/compensation/shadow", summary="Shadow mode on or off (technician)")
    async def shadow(body: ShadowIn, caller: Caller = technician) -> dict:
        return await apply(replace(comp.settings, shadow=body.shadow), caller)

    @r.post("/compensation/command", summary="Reset compensation, record an insert change or "
            "acknowledge an alarm")
    async def command(body: CommandIn, caller: Caller = technician) -> dict:
        tool = body.tool
        if body.command == "insert_change" and tool is None:  # the one tool's, if one
            tools = sorted({e.tool for e, _ in comp.in_force()})
            if len(tools) != 1:
                raise HTTPException(422, "tool: an insert change names the tool whose insert "
                                    f"was changed (the job's tools: {tools})")
            tool = tools[0]
        if tool is not None:  # one tool's: not a command of the CNC's registers
            who = f"api:{caller}"
            try:
                d = await (comp.reset("api", who, tool) if body.command == "reset"
                           else comp.insert_change(who, tool)
                           if body.command == "insert_change"
                           else comp.acknowledge(who, tool))
            except KeyError as err:
                raise HTTPException(404, err.args[0]) from None
            return {"decision": d.as_dict(), "state": comp.state.value}
        code = Command.RESET_COMPENSATION if body.command == "reset" \
            else Command.ACKNOWLEDGE_ALARM
        d = await run_command(code, source="api", who=f"api:{caller}")
        return {"decision": None if d is None else d.as_dict(), "state": comp.state.value}

    @r.get("/compensation/log", summary="Compensation decisions, newest first")
    def offset_log(limit: int = Query(100, ge=1, le=5000),
                   before_id: int | None = Query(None, ge=1, le=2**63 - 1),
                   kinds: str | None = Query(None, description="comma-separated kinds")
                   ) -> dict:
        if log is None:
            raise HTTPException(503, f"the compensation log cannot be used: {store_error}")
        try:
            wanted = tuple(Kind(k.strip()).value for k in kinds.split(",")) if kinds \
                else None
        except ValueError:
            raise HTTPException(422, f"kinds: {kinds!r} holds an unknown kind (known: "
                                f"{', '.join(k.value for k in Kind)})") from None
        items = log.decisions(limit, before_id, wanted)
        return {"items": items, "next_before_id": items[-1]["id"] if len(items) == limit
                else None}

    @r.get("/temperature", summary="Part temperature for the diameter at 20 C")
    def temperature() -> dict:
        return {"part_temp_c": comp.part_temp_c, "alpha_per_k": comp.alpha_per_k}

    @r.put("/temperature", summary="Set the part temperature (technician)")
    async def set_temperature(body: TemperatureIn, caller: Caller = technician) -> dict:
        await comp.set_temperature(body.part_temp_c, body.alpha_per_k, who=f"api:{caller}")
        return temperature()

    return r
