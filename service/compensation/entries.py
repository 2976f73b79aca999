"""One controller per tool, over the features each finishes (time passed in).

``JobCompensation`` routes a measurement of a feature to the controller of the tool that
finishes it: each tool has its own law, limits, offset handshake and persisted state, so an
offset never reaches another tool. A tool finishing several features takes them into one
law, each less its empirical value, and is held while they disagree (``combine``).
"""

from __future__ import annotations

import math
from dataclasses import replace

from service.compensation.combine import FeatureAgreement, aim
from service.compensation.controller import CompensationController
from service.compensation.job import Job, JobFeature, OffsetEntry
from service.compensation.records import (
    ControllerState,
    Decision,
    FeatureTerms,
    Kind,
    MeasurementIn,
)
from service.compensation.settings import CompensationSettings


class EntryCompensation:
    """One offset entry's compensation (a tool's own, or another offset of the same insert):
    a ``CompensationController`` with the tool's law and limits, judging each measurement
    against its feature's nominal and bands."""

    def __init__(self, job: Job, entry: OffsetEntry | int, base: CompensationSettings,
                 state: ControllerState | None = None,
                 controller: CompensationController | None = None) -> None:
        self.entry = entry if isinstance(entry, OffsetEntry) else OffsetEntry(entry)
        self.job, self.tool, self.base = job, self.entry.tool, base
        features = job.features_on(self.entry)
        if not features:
            raise KeyError(f"{self.entry} corrects no feature of job {job.part_number!r}")
        # The tool's law and limits; its reference feature is the first it finishes. A
        # running service brings its own controller (its settings and persisted state).
        self.controller = controller or CompensationController(
            job.settings_for(features[0], base), state or ControllerState())
        self.agreement = FeatureAgreement()

    def rebase(self, base: CompensationSettings) -> None:
        """New settings under the job's features (a technician changed them)."""
        self.base = base

    def terms(self, feature: JobFeature) -> FeatureTerms:
        """How the tool takes a measurement of ``feature`` now: less its empirical value and
        its learnt difference from where the tool is aimed (``combine.aim``)."""
        levels = self.agreement.relative_levels()
        shift = 0.0
        if feature.number in levels:
            tolerances = {f: (self.job.feature(f).tol_lower_mm, self.job.feature(f).tol_upper_mm)
                          for f in levels}
            shift = levels[feature.number] - aim(levels, tolerances)
        return FeatureTerms(self.job.settings_for(feature, self.base),
                            feature.empirical_mm + shift,
                            self.agreement.disagreement(self.job.max_disagreement_mm(self.entry)))

    def on_measurement(self, m: MeasurementIn, now: float, feature: JobFeature) -> Decision:
        """Judge a measurement of ``feature``, one of this entry's."""
        if self.job.entry_of(feature) != self.entry:
            raise ValueError(f"feature {feature.number} is corrected on "
                             f"{self.job.entry_of(feature)}, not {self.entry}")
        if m.status == "ok" and m.diameter_mm is not None and m.uncertainty_mm is not None \
                and math.isfinite(m.diameter_mm):
            self.agreement.add(feature.number,
                               m.diameter_mm - feature.nominal_mm - feature.empirical_mm,
                               m.uncertainty_mm, m.time_s)
        d = self.controller.on_measurement(m, now, self.terms(feature))
        if d.kind is Kind.WRITE:
            self.agreement.applied()  # the next parts are cut with it
        return d


class JobCompensation:
    """The controllers of a job's offset entries, and the routing of a feature's measurement
    to its entry's."""

    def __init__(self, job: Job, base: CompensationSettings,
                 states: dict[OffsetEntry, ControllerState] | None = None) -> None:
        self.job = job
        self.entries = {e: EntryCompensation(job, e, base, (states or {}).get(e))
                        for e in job.entries()}

    @property
    def tools(self) -> dict[int, EntryCompensation]:
        """Each tool's own entry's compensation, by T number."""
        return {e.tool: c for e, c in self.entries.items() if e.number is None}

    def on_measurement(self, m: MeasurementIn, now: float, feature_number: int
                       ) -> tuple[OffsetEntry, Decision]:
        """(entry, decision) for a measurement of ``feature_number`` (KeyError naming the
        job's features when it has no such feature)."""
        feature = self.job.feature(feature_number)
        entry = self.job.entry_of(feature)
        return entry, self.entries[entry].on_measurement(m, now, feature)

    def shadow(self, on: bool, now: float) -> None:
        """Shadow mode for every entry."""
        for t in self.entries.values():
            t.controller.update_settings(replace(t.controller.settings, shadow=on), now)
