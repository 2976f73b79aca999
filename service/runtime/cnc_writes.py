"""What the CNC writes into the registers: checked whole against the settings and the job's
rules before anything is taken (``CncWriteRules``), then carried out (``CncCommands``: the
feature, the job, the part counter, and the commands, which the API runs too)."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import Awaitable, Callable
from dataclasses import replace

from calib_store.store import NotStoredError
from drivers.plc.registers import BY_NAME, Command, units_to_mm
from service.compensation import Decision
from service.compensation.job import Job, JobError, job_from_doc
from service.config import ModbusSettings
from service.runtime.compensating import CompensationService
from service.runtime.job_service import JobService
from service.runtime.register_view import RegisterView

log = logging.getLogger("shaftgauge.modbus")

_FEATURE = {"nominal": "nominal_mm", "tol_upper": "tol_upper_mm", "tol_lower": "tol_lower_mm"}


def feature_changes(entries: list[tuple[str, int]]) -> dict[str, float | None]:
    """The nominal and tolerances a write holds, mm (None: cleared)."""
    return {_FEATURE[name]: units_to_mm(value) for name, value in entries if name in _FEATURE}


def _not_in(job: Job | None, name: str, feature: int) -> str:
    """Why ``feature``, written as ``name``, cannot be taken: no job in force, or none such
    in it ("" when it can)."""
    if job is None:
        return f"{name}: no job is in force"
    try:
        job.feature(feature)
    except KeyError as err:
        return f"{name}: {err.args[0]}"
    return ""


class CncWriteRules:
    """Why a CNC's write cannot be taken, by the settings' and the job's rules (the server
    refuses it whole, exception 0x03)."""

    def __init__(self, settings: ModbusSettings, compensation: CompensationService) -> None:
        self.settings, self.compensation = settings, compensation
        self.jobs: JobService | None = None

    def _check_jobs(self, entries: list[tuple[str, int]]) -> str:
        """Why the job, feature, tool or entry written cannot be taken ("" when it can)."""
        values = dict(entries)
        if self.jobs is None or not {"job", "feature", "cnc_tool", "cnc_entry",
                                     "measure_request"} & values.keys():
            return ""
        job = self.jobs.job
        if values.get("job"):
            if self.jobs.store is None:
                return f"job: the store cannot be used ({self.jobs.store_error})"
            try:
                job = job_from_doc(self.jobs.store.newest_of(values["job"]).document)
            except KeyError as err:
                return f"job: {err.args[0]}"
            except JobError as err:
                return f"job {values['job']}: {err}"
        if values.get("feature") and (why := _not_in(job, "feature", values["feature"])):
            return why
        if values.get("measure_request"):
            if "measure_feature" not in values:  # the pair in one write: never half a request
                return ("measure_request: write measure_feature with it, in the same write "
                        f"(registers {BY_NAME['measure_feature'].address}-"
                        f"{BY_NAME['measure_request'].address})")
            if why := _not_in(job, "measure_feature", values["measure_feature"]):
                return why
        tool = values.get("cnc_tool")
        # The settings' single feature has whatever tool the CNC compensates.
        if tool and self.jobs.stored is not None and (job is None
                                                      or tool not in job.tool_numbers()):
            return (f"cnc_tool: tool {tool} is not in "
                    + ("any job: none is in force" if job is None else
                       f"job {job.part_number!r} (its tools: "
                       f"{', '.join(str(t) for t in job.tool_numbers())})"))
        entry = values.get("cnc_entry")
        numbers = sorted({e.number for e in job.entries() if e.number}) if job else []
        if entry and self.jobs.stored is not None and entry not in numbers:
            return (f"cnc_entry: offset entry {entry} is not in "
                    + ("any job: none is in force" if job is None else
                       f"job {job.part_number!r} (its entries other than tools' own: "
                       f"{', '.join(map(str, numbers)) or 'none'})"))
        return ""

    def check(self, entries: list[tuple[str, int]]) -> str:
        """Why a write cannot be taken ("" when it can): a command the settings keep from the
        CNC, a job or feature the gauge does not have, or a feature that does not hold
        together. A write is taken whole or not at all,
        so a refused one leaves ``command`` and ``last_command`` as they were."""
        for name, value in entries:
            if name != "command":
                continue
            if value == Command.RESET_COMPENSATION and not self.compensation.reset_command:
                return ("command 2 (reset) from the CNC is off (modbus.reset_command): a "
                        "technician resets over the API")
            if value == Command.ACKNOWLEDGE_ALARM and not self.settings.acknowledge_command:
                return ("command 3 (acknowledge) from the CNC is off "
                        "(modbus.acknowledge_command): a technician acknowledges over the API")
        problem = self._check_jobs(entries)
        if problem:
            return problem
        changes = feature_changes(entries)
        if not changes:
            return ""
        if self.compensation.log is None:
            return f"the store cannot be used ({self.compensation.store_error})"
        try:
            problems = replace(self.compensation.settings, **changes).problems()
        except (TypeError, ValueError) as err:
            return str(err)
        return "; ".join(problems)


class CncCommands:
    """Carries out what the CNC wrote (the rules passed it) and the commands of the API.

    Parameters
    ----------
    settings : ModbusSettings
        Which commands the CNC may give.
    compensation : CompensationService
        Where the feature and the commands go.
    view : RegisterView
        Shows what is in force again when a write could not be taken after all, and
        acknowledges each command.
    trigger : callable
        ``trigger()``: the camera takes a frame now (the measure-now command).
    """

    def __init__(self, settings: ModbusSettings, compensation: CompensationService,
                 view: RegisterView, trigger: Callable[[], None]) -> None:
        self.settings, self.compensation, self.view = settings, compensation, view
        self.trigger = trigger
        self.jobs: JobService | None = None
        self._tasks: set[asyncio.Task] = set()

    def take(self, entries: list[tuple[str, int]], peer: str) -> None:
        """A CNC wrote registers, the whole write at once (called inside the Modbus server, on
        the event loop)."""
        who = f"modbus:{peer}" if peer else "modbus"
        changes = feature_changes(entries)
        if changes:
            self._spawn(self._feature_from_cnc(changes, who))
        values = dict(entries)
        if "part_counter" in values and self.jobs is not None:
            self.jobs.part_counter = values["part_counter"] or None
        if "job" in values or "feature" in values:
            self._spawn(self._job_from_cnc(values.get("job"), values.get("feature"), who))
        if "measure_request" in values and self.jobs is not None:
            try:
                self.jobs.request_measurement(values["measure_request"],
                                              values.get("measure_feature", 0), time.time())
            except KeyError as err:  # the job changed since the check
                log.warning("measure request from %s not taken: %s", who, err)
        for name, value in entries:
            if name == "command":
                self._spawn(self.run_command(Command(value), source="modbus", who=who))

    def _spawn(self, coro: Awaitable[object]) -> None:
        task = asyncio.get_running_loop().create_task(coro)  # type: ignore[arg-type]
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    async def _feature_from_cnc(self, changes: dict[str, float | None], who: str) -> None:
        try:
            assert self.jobs is not None  # wired before the server starts
            await self.jobs.set_feature(who, **changes)
        except (ValueError, NotStoredError) as err:  # changed meanwhile, or not storable
            log.warning("feature from %s not taken: %s", who, err)
            self.view.job_changed()  # the registers show what is in force

    async def _job_from_cnc(self, job_id: int | None, feature: int | None, who: str) -> None:
        """The job, then the feature, the CNC wrote (checked before the write was taken)."""
        jobs = self.jobs
        assert jobs is not None
        try:
            if job_id == 0:
                jobs.deactivate(who)
            elif job_id is not None and jobs.store is not None:  # a job's number: its
                await jobs.activate(jobs.store.newest_of(job_id).id, who)  # newest version
            if feature is not None:
                jobs.select(feature or None)
        except (KeyError, ValueError, NotStoredError) as err:  # changed meanwhile
            log.warning("job or feature from %s not taken: %s", who, err)
            self.view.job_changed()  # the registers show what is in force

    async def run_command(self, command: Command, source: str,
                          who: str | None = None) -> Decision | None:
        """Carry out a command (from the CNC or the API) and acknowledge it in the
        registers."""
        decision = None
        who = who or source
        if command is Command.RESET_COMPENSATION:
            decision = await self.compensation.reset(source, who)
        elif command is Command.ACKNOWLEDGE_ALARM:
            if source == "modbus" and not self.settings.acknowledge_command:
                log.warning("alarm acknowledgement from %s refused: acknowledgements from the "
                            "CNC's command register are off (modbus.acknowledge_command); a "
                            "technician acknowledges over the API", who)
            else:
                decision = await self.compensation.acknowledge(who)
        elif command is Command.MEASURE_NOW:
            with contextlib.suppress(Exception):  # a free-running camera measures anyway
                self.trigger()
        self.view.command_done(command)
        log.info("command %s from %s", command.name.lower(), who)
        return decision
