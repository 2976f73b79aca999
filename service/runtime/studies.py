"""Type-1 gauge studies run in the lathe: the master measured ``n`` times with offsets held,
the figures kept, and the gate that blocks offset writes while the gauge is not proven
capable."""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from calib_store.gauge_studies import GaugeStudyStore
from service.quality.gauge_study import type1_study
from service.runtime.compensating import CompensationService
from service.runtime.feed import MeasurementFeed

log = logging.getLogger("shaftgauge.studies")

VALUE_TIMEOUT_S = 30.0
"""A study fails when no good measurement of the master comes for this long."""
FAR_FROM_MASTER = 1.0
"""A value farther than this many tolerances (T) from the certified size is not the master's
(another surface under the laser, a feature of the part): refused and counted, never kept.
A capable gauge's values lie within a few hundredths of T of it."""


@dataclass(frozen=True)
class StudyPolicy:
    """When a study blocks offset writes.

    ``max_age_h``: a study older than this blocks (None: no period); ``min_index``: Cg and
    Cgk below it block; ``required``: no study yet blocks; ``resolution_mm``: the gauge's
    reported resolution (for the 5 % check).
    """

    max_age_h: float | None = None
    min_index: float = 1.33
    required: bool = False
    resolution_mm: float = 0.0001


class StudyError(RuntimeError):
    """A study that cannot start now (one is running, no nominal, ...)."""


class GaugeStudies:
    """Runs one study at a time and says whether the latest one allows offset writes.

    Parameters
    ----------
    store : GaugeStudyStore or None
        Where studies are kept (None: the store cannot be used; studies cannot run).
    feed : MeasurementFeed
        The measurements (a study takes each value as a fused value of new frames).
    compensation : CompensationService
        Holds offsets during a study.
    fuse_frames : int
        Good measurements per value (a new set of frames each).
    policy : StudyPolicy
        When the result blocks offset writes.
    calibration_id : callable
        The calibration in force.
    """

    def __init__(self, store: GaugeStudyStore | None, feed: MeasurementFeed,
                 compensation: CompensationService, fuse_frames: int, policy: StudyPolicy,
                 calibration_id: Callable[[], int | None]) -> None:
        self.store, self.feed, self.compensation = store, feed, compensation
        self.fuse_frames, self.policy, self.calibration_id = fuse_frames, policy, calibration_id
        self.running: dict[str, Any] | None = None
        self._task: asyncio.Task | None = None
        self._latest = store.latest_done() if store is not None else None

    def start(self, certified_mm: float, n: int, tolerance_mm: float, by: str,
              feature: int | None = None) -> int:
        """Start a study (of a master of the job's ``feature``, when named); its id. Raises
        ``StudyError`` when one cannot start now."""
        if self.store is None:
            raise StudyError("the store cannot be used: studies are not kept")
        if self.running is not None:
            raise StudyError(f"study {self.running['id']} is running "
                             f"({len(self.running['values'])} of {self.running['n']} values)")
        sid = self.store.start(time.time(), by, self.calibration_id(), certified_mm,
                               tolerance_mm, n, feature)
        self.running = {"id": sid, "n": n, "values": [], "certified_mm": certified_mm,
                        "tolerance_mm": tolerance_mm, "by": by, "started": time.time(),
                        "feature": feature, "refused": 0}
        self._task = asyncio.get_running_loop().create_task(self._run(sid), name="study")
        return sid

    async def _run(self, sid: int) -> None:
        run = self.running
        assert run is not None
        owner = f"study-{sid}"
        values: list[float] = run["values"]
        queue = self.feed.subscribers.add()
        state, reason, result = "failed", "", None
        try:
            kept_at = time.monotonic()
            while len(values) < run["n"]:
                self.compensation.hold_offsets(VALUE_TIMEOUT_S * 2, f"gauge study {sid} "
                                               "running: the master is in the lathe",
                                               owner, code="gauge_study")
                value = await self._next_value(queue, run["started"])
                if abs(value - run["certified_mm"]) <= FAR_FROM_MASTER * run["tolerance_mm"]:
                    values.append(value)
                    kept_at = time.monotonic()
                    continue
                run["refused"] += 1
                run["last_refused_mm"] = value
                if time.monotonic() - kept_at > VALUE_TIMEOUT_S:
                    raise TimeoutError
            study = type1_study(values, run["certified_mm"], run["tolerance_mm"],
                                resolution=self.policy.resolution_mm,
                                min_index=self.policy.min_index)
            state, result = "done", study.as_dict()
        except TimeoutError:
            reason = (f"no good measurement of the master for {VALUE_TIMEOUT_S:g} s after "
                      f"{len(values)} of {run['n']} values")
        except asyncio.CancelledError:
            reason = "the service stopped during the study"
            raise
        finally:
            if run["refused"]:
                reason = "; ".join(r for r in (reason, (
                    f"{run['refused']} values refused as not the master's (farther than "
                    f"{FAR_FROM_MASTER * run['tolerance_mm']:g} mm, one T, from "
                    f"{run['certified_mm']:g} mm; the last {run['last_refused_mm']:.4f} mm)"))
                    if r)
            self.feed.subscribers.remove(queue)
            self.compensation.release_hold(owner)
            await asyncio.shield(asyncio.to_thread(
                self.store.finish, sid, time.time(), state, list(values), result, reason))
            if result is not None:
                self._latest = {"id": sid, "finished": time.time(), "result": result,
                                "state": "done"}
            self.running = None
            log.info("gauge study %d %s%s", sid, state, f": {reason}" if reason else "")

    async def _next_value(self, queue: asyncio.Queue, since: float) -> float:
        """The fused value of ``fuse_frames`` new good measurements of frames received after
        ``since`` (Unix seconds): frames still in the pipeline when the study started may
        show what was in the lathe before the master."""
        good = 0
        async with asyncio.timeout(VALUE_TIMEOUT_S) as deadline:
            while True:
                record = await queue.get()
                if record.status != "ok" or record.diameter_mm is None \
                        or record.time - record.latency_ms / 1000.0 < since:
                    continue
                deadline.reschedule(asyncio.get_running_loop().time() + VALUE_TIMEOUT_S)
                good += 1
                if good >= self.fuse_frames and record.fused_diameter_mm is not None:
                    return float(record.fused_diameter_mm)

    def blocking(self, now: float | None = None) -> str | None:
        """Why offset writes are blocked by the studies, or None."""
        latest, p = self._latest, self.policy
        if latest is None:
            return "no type-1 gauge study yet (quality.study_required)" if p.required else None
        r = latest["result"]
        if not r["capable"]:
            return (f"gauge study {latest['id']} failed: " + "; ".join(r["reasons"]))
        if p.max_age_h is not None:
            age_h = ((now or time.time()) - latest["finished"]) / 3600.0
            if age_h > p.max_age_h:
                return (f"gauge study {latest['id']} is {age_h:.1f} h old (more than "
                        f"quality.study_max_age_h = {p.max_age_h:g})")
        return None

    def status(self) -> dict[str, Any]:
        """The running study's progress and the latest result, JSON-ready."""
        run = self.running
        return {"running": None if run is None else {
            "id": run["id"], "n": run["n"], "done": len(run["values"]),
            "values_mm": list(run["values"]), "certified_mm": run["certified_mm"],
            "tolerance_mm": run["tolerance_mm"], "refused": run["refused"]},
            "latest": self._latest, "blocking": self.blocking()}

    async def stop(self) -> None:
        """Cancel a running study (it is kept as failed), then close the store."""
        if self._task is not None and not self._task.done():
            self._task.cancel()
            await asyncio.gather(self._task, return_exceptions=True)
        if self.store is not None:
            self.store.close()
