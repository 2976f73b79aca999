"""The job in force: the part program's features and tools, which feature is under the
laser, and the records of the parts as they are finished. One owner of all three.

With no stored job active, the job is today's one feature: the compensation settings'
nominal and tolerance, finished by tool 1 (``Job.single``); a stored job in force leaves the
settings as they are, whatever its number of features. Every job is measured feature by feature and
recorded part by part; each measurement goes into its feature's offset entry's law against
its own feature (``CompensationService.set_job``, a channel an entry).
"""

from __future__ import annotations

import logging
import sqlite3
import time
from collections.abc import Callable
from typing import Any

from calib_store.job_store import JobInfo, JobStore
from calib_store.store import NotStoredError
from service.compensation import Decision
from service.compensation.job import Job, JobError, JobFeature, job_from_doc
from service.measurement_record import Feature, MeasurementRecord
from service.quality.parts import PartAssembler, PartRecord
from service.quality.results import Answer, MeasureHandshake, PartResults, Results
from service.runtime.compensating import CompensationService
from service.runtime.listeners import Listeners
from service.runtime.part_log import PartLog

log = logging.getLogger("shaftgauge.jobs")



class JobService:
    """Owns the active job, the feature under the laser and the part records (the part under
    way and what the part program reads back of it; ``part_log``, the parts finished).

    Parameters
    ----------
    store : JobStore or None
        Where jobs and parts are kept (None: ``store_error`` says why not).
    compensation : CompensationService
        Its settings are the single feature's when no stored job is active.
    store_error : str
        Why there is no store.
    handshake : MeasureHandshake, optional
        The "feature measured" requests' (``service.quality.results``).
    """

    def __init__(self, store: JobStore | None, compensation: CompensationService,
                 store_error: str = "", handshake: MeasureHandshake | None = None) -> None:
        self.store, self.compensation, self.store_error = store, compensation, store_error
        self.stored: JobInfo | None = None
        self.not_taken: JobInfo | None = None
        """The job the store marks active that the compensation could not take (a start)."""
        self.selected: int | None = None
        self._feature_set = compensation.feature()  # the settings' single feature, as seen
        self._in_view: int | None = None  # the feature measured last (the registers show it)
        self.part_log = PartLog(store)
        self.latest: dict[int, MeasurementRecord] = {}  # by feature, of the job in force
        self.part_counter: int | None = None  # the CNC's, when it counts (map v4)
        self._changes: Listeners[None] = Listeners("job or feature changed")
        self._new_jobs: Listeners[None] = Listeners("job put in force")
        self.results_kept = PartResults(handshake or MeasureHandshake())
        self._results: Listeners[None] = Listeners("results changed")
        self.refused = 0
        self.last_refused = ""
        if store is not None:
            try:
                self.stored = store.active()
            except (sqlite3.Error, ValueError) as err:
                self.store_error = f"the active job cannot be read: {err}"
        self._job: Job | None = None
        self.parts: PartAssembler | None = None
        self._parts_job: int | None = None  # the stored job the part under way is of
        self._rebuild()

    def on_change(self, listener: Callable[[], None]) -> None:
        """Call ``listener()`` whenever the job in force or the feature named changes."""
        self._changes.add(lambda _: listener())

    def on_new_job(self, listener: Callable[[], None]) -> None:
        """Call ``listener()`` whenever another job (or the single feature anew) is in force."""
        self._new_jobs.add(lambda _: listener())

    def _changed(self) -> None:
        self._changes.tell(None)

    def on_results(self, listener: Callable[[], None]) -> None:
        """Call ``listener()`` whenever what ``results()`` gives may have moved."""
        self._results.add(lambda _: listener())

    # ---- the job ------------------------------------------------------------------------

    @property
    def job(self) -> Job | None:
        """The job in force (None: no stored job and no nominal set)."""
        return self._job

    def _rebuild(self) -> None:
        """The job from the store, or the single feature from the settings; the part under
        way ends with the job it belonged to."""
        if self.parts is not None:
            self._record(self.parts.finish())
        job = self._stored_job()  # taken by the compensation already
        if job is None:
            if self.compensation.settings.nominal_mm is not None:
                job = Job.single(self.compensation.settings)
            self.compensation.set_job(job)
        self._job = job
        self._feature_set = self.compensation.feature()
        self.selected = None
        self._in_view = None
        self.latest = {}
        self.parts = PartAssembler(job) if job is not None else None
        self._parts_job = None if self.stored is None else self.stored.id
        self._new_jobs.tell(None)
        self._changed()

    def _stored_job(self) -> Job | None:
        """The stored job marked active, once the compensation has taken it; else None, and
        ``store_error`` and the log say why (a start then goes on with the settings' single
        feature rather than not at all; ``not_taken`` keeps the job refused)."""
        if self.stored is None:
            return None
        try:
            job = job_from_doc(self.stored.document, self.compensation.settings)
            self.compensation.set_job(job)
        except (JobError, ValueError) as err:  # a job an older release took, say
            self.store_error = (
                f"stored job {self.stored.id} ({self.stored.part_number} version "
                f"{self.stored.version}) cannot be put in force: {err}; the settings' single "
                "feature is in force instead (DELETE /api/v1/jobs/active or `shaftgauge job "
                "deactivate` takes it out of force)")
            log.error("%s", self.store_error)
            self.not_taken, self.stored = self.stored, None  # the store still marks it
            return None
        return job

    def settings_changed(self) -> None:
        """The compensation settings changed (a listener): the single feature follows; a
        feature set directly (the API's feature, the CNC's nominal) ends a stored job."""
        if self.compensation.feature() == self._feature_set:
            return  # the job's own feature going in, or another setting: the job stands
        if self.stored is not None:
            log.warning("job %s no longer in force: a feature was set directly",
                        self.stored.part_number)
            self.deactivate("a feature set directly")
        else:
            self._rebuild()

    async def set_feature(self, who: str, **changes: float | None) -> Decision:
        """A feature set directly (the API's, the CNC's nominal registers): the settings'
        single feature, changed, becomes the job in force; a stored job ends (ValueError
        while inconsistent, NotStoredError when it cannot be kept: nothing changed)."""
        d = await self.compensation.update_feature(who, **changes)
        if self.stored is not None:  # the same feature as before ends it too
            log.warning("job %s no longer in force: a feature was set directly",
                        self.stored.part_number)
            self.deactivate("a feature set directly")
        return d

    def _store(self) -> JobStore:
        if self.store is None:
            raise NotStoredError(f"not stored, nothing changed: the store cannot be used "
                                 f"({self.store_error})")
        return self.store

    async def add(self, document: Any, by: str, note: str = "", activate: bool = False
                  ) -> JobInfo:
        """Store a job document as its part number's next version (JobError naming the field
        of a bad one; NotStoredError when it cannot be stored)."""
        job = job_from_doc(document, self.compensation.settings)
        jid = self._store().add(job.to_doc(), by, note, activate=False)
        if activate:
            await self.activate(jid, by)
        return self._store().get(jid)

    async def activate(self, job_id: int, by: str) -> JobInfo:
        """Make a stored job the one in force (KeyError when there is none of that id;
        JobError naming what the runtime refused, the job in force left as it was). The
        runtime takes the job before the store marks it active: one transaction."""
        info = self._store().get(job_id)
        job = job_from_doc(info.document, self.compensation.settings)
        try:
            self.compensation.set_job(job)
        except ValueError as err:
            self.compensation.set_job(self._job)
            raise JobError(f"job {job_id}: {err}") from None
        self._store().activate(job_id, by)
        if self.not_taken is not None:  # another job in its place: what was said is past
            self.not_taken, self.store_error = None, ""
        self.stored = self._store().get(job_id)
        self._rebuild()
        log.info("job %s version %d in force (%s)", info.part_number, info.version, by)
        return self.stored

    def deactivate(self, by: str) -> None:
        """Back to the single feature of the compensation settings (also when the job the
        store marks active could not be put in force)."""
        ending = self.stored or self.not_taken
        if ending is not None:
            log.info("job %s no longer in force (%s)", ending.part_number, by)
            if self.store is not None:
                try:
                    self.store.deactivate(by)
                    if self.not_taken is not None:
                        self.not_taken, self.store_error = None, ""
                except sqlite3.Error as err:  # in force now; a restart brings it back
                    log.error("the job's end not stored: %s", err)
        self.stored = None
        self._rebuild()

    def select(self, feature: int | None) -> None:
        """The feature under the laser, as the CNC or a person names it (None: recognised
        from the diameter). KeyError naming the job's features when it has no such one."""
        if feature is not None:
            if self._job is None:
                raise KeyError("no job is in force (set a nominal, or activate a job)")
            self._job.feature(feature)
        self.selected = feature
        self._changed()

    # ---- the measurements ----------------------------------------------------------------

    def assign(self, diameter_mm: float | None) -> tuple[JobFeature | None, str]:
        """Which feature a diameter is: the one named, or the one recognised; (None, why)
        when none fits (never a guess)."""
        job = self._job
        if job is None or diameter_mm is None:
            return None, ""
        if self.selected is not None:
            other = self.results_kept.another_features(job, self.selected, diameter_mm)
            return (None, other) if other else (job.feature(self.selected), "")
        if len(job.features) == 1:
            return job.features[0], ""
        found = job.recognise(diameter_mm)
        if found.feature is None:
            self.refused += 1
            self.last_refused = found.reason
        return found.feature, found.reason

    def feature_in_view(self) -> Feature:
        """The feature the CNC's registers show: the one named, else the one measured last,
        else the job's first (none without a job)."""
        job = self._job
        if job is None:
            return Feature(None, 0.0, 0.0)
        number = self.selected if self.selected is not None else self._in_view
        return self.feature_of(job.feature(number) if number is not None
                               else job.features[0])

    @staticmethod
    def feature_of(feature: JobFeature | None) -> Feature:
        """What a measurement of ``feature`` is compared with."""
        if feature is None:
            return Feature(None, 0.0, 0.0)
        return Feature(feature.nominal_mm, feature.tol_lower_mm, feature.tol_upper_mm)

    def feature_for(self, record: MeasurementRecord) -> Feature:
        """What ``record`` was compared with (its feature's nominal and tolerance)."""
        try:
            return self.feature_of(None if self._job is None or record.feature is None
                                   else self._job.feature(record.feature))
        except KeyError:  # measured under the job before this one
            return Feature(None, 0.0, 0.0)

    def published(self, record: MeasurementRecord) -> None:
        """A published measurement (a feed listener): into the part under way, and to the
        "feature measured" request waiting."""
        if record.feature is not None:
            self.latest[record.feature] = record
            if record.feature != self._in_view:
                self._in_view = record.feature
                self._changed()  # the registers show the feature under the laser
        good = self.parts is not None and record.feature is not None \
            and record.status == "ok" and record.diameter_mm is not None \
            and record.uncertainty_mm is not None
        if good:
            assert self.parts is not None and record.feature is not None
            self._record(self.parts.add(record.feature, record.compensation_diameter_mm,
                                        record.uncertainty_mm, record.time, self.part_counter))
        answer = self.results_kept.measured(record.feature, good, record.status,
                                            record.time - record.latency_ms / 1e3, time.time())
        if answer is not None or good:
            self._answered(answer)

    def request_measurement(self, seq: int, feature: int, now_s: float) -> None:
        """The CNC's "feature measured" request at wall-clock ``now_s`` (``results``: the
        feature named until answered; KeyError when the job has no such feature)."""
        changed, name = self.results_kept.request(seq, feature, now_s, self.selected)
        if name != self.selected:
            self.select(name)
        if changed:
            self._results.tell(None)

    def tick(self, now_s: float) -> None:
        """A request whose time ran out with no measurement (the camera away): refused."""
        if (answer := self.results_kept.tick(now_s)) is not None:
            self._answered(answer)

    def _answered(self, answer: Answer | None) -> None:
        """The results moved (``answer``: a request answered)."""
        kept, p = self.results_kept, self.parts
        if answer is not None and kept.answered_with(answer, p.under_way() if p else None) \
                and kept.named_before != self.selected:
            self.select(kept.named_before)  # named as it was before the request
        self._results.tell(None)

    def results(self) -> Results:
        """What the part program reads back now (``service.quality.results.Results``)."""
        p = self.parts
        return self.results_kept.now(self._job, p.under_way() if p else None,
                                     p.number if p else 0)

    def _record(self, part: PartRecord | None) -> None:
        if part is not None:  # a part finished
            self.results_kept.finished(part)
            self.part_log.add(part, self._parts_job)  # the job it was of, not the next

    def status(self) -> dict[str, Any]:
        """The job's part of the service status."""
        job = self._job
        return {"job": None if job is None else {
                    "id": None if self.stored is None else self.stored.id,
                    "part_number": job.part_number,
                    "version": None if self.stored is None else self.stored.version,
                    "features": len(job.features), "tools": len(job.tool_numbers())},
                "feature_selected": self.selected,
                "offsets_held": self.compensation.entries.blocked() or None,
                "refused_diameters": self.refused, "last_refused": self.last_refused or None,
                "store_error": self.store_error or None}
