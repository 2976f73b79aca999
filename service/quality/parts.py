"""One record per part: the measurements of a part's features gathered into its fused
diameters and verdicts, and the part's own verdict.

A part ends when the CNC's part counter moves on. With no counter the gauge counts the
parts itself: a part ends when the laser comes back to a feature the part already has after
another one, or when nothing was measured for ``gap_s`` (the part left the gauge). Several
measurements of one feature in a row (frames along a segment, turning continuously) are
fused: their mean weighted by 1 / uncertainty^2.

Pure: measurements in, ``PartRecord`` out. Lengths in mm of diameter.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

from service.compensation.job import Job, JobFeature


@dataclass(frozen=True)
class FeatureResult:
    """A feature of one part: its fused diameter, their uncertainty, how many measurements,
    and the verdict against its tolerance (``ok``, ``above``, ``below``; ``missing`` when
    the part went by without it)."""

    feature: int
    name: str
    nominal_mm: float
    diameter_mm: float | None
    uncertainty_mm: float | None
    n: int
    verdict: str
    tol_lower_mm: float = 0.0
    tol_upper_mm: float = 0.0


@dataclass(frozen=True)
class PartRecord:
    """One finished part (``verdict``: ``ok``, ``out`` when a feature is out of tolerance,
    ``incomplete`` when one was not measured)."""

    serial: str
    time_s: float
    part_number: str
    features: tuple[FeatureResult, ...]
    verdict: str
    number: int = 0
    """The CNC's part counter, or the gauge's own count when the CNC counts none."""

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return asdict(self)


def judge(feature: JobFeature, diameter_mm: float) -> str:
    """``ok``, ``above`` or ``below`` its tolerance."""
    deviation = diameter_mm - feature.nominal_mm
    if deviation > feature.tol_upper_mm:
        return "above"
    if deviation < feature.tol_lower_mm:
        return "below"
    return "ok"


@dataclass
class PartAssembler:
    """Gathers measurements into parts (see the module's docstring)."""

    job: Job
    gap_s: float = 10.0
    """With no counter, a pause this long ends the part."""
    next_own: int = 1
    """The gauge's own count, for parts the CNC does not number."""
    _counter: int | None = None
    _started: float = 0.0
    _last: tuple[int, float] | None = None  # the feature and time last measured
    _values: dict[int, list[float]] = field(default_factory=dict)
    """Each feature's fusion so far: [sum of weights, sum of weight x (d - first d), count,
    first d] (running sums: a part of one feature measured all shift long is one part)."""

    def add(self, feature: int, diameter_mm: float, uncertainty_mm: float, time_s: float,
            part_counter: int | None = None) -> PartRecord | None:
        """A measurement of ``feature`` (KeyError when the job has none); the part it
        finished, if it finished one."""
        self.job.feature(feature)
        done = None
        if part_counter is not None:
            new_part = part_counter != self._counter
        else:
            back = feature in self._values and self._last is not None \
                and self._last[0] != feature
            new_part = back or (self._last is not None
                                and time_s - self._last[1] > self.gap_s)
        if self._values and new_part:
            done = self.finish()
        if not self._values:
            self._started, self._counter = time_s, part_counter
        w = 1.0 / max(uncertainty_mm, 1e-6) ** 2
        acc = self._values.setdefault(feature, [0.0, 0.0, 0, diameter_mm])
        acc[0] += w
        acc[1] += w * (diameter_mm - acc[3])
        acc[2] += 1
        self._last = (feature, time_s)
        return done

    def finish(self) -> PartRecord | None:
        """End the part under way now (the job changes, the service stops); None when no
        feature of it was measured."""
        if not self._values:
            return None
        record = self.under_way()
        if self._counter is None:
            self.next_own += 1
        self._values, self._counter, self._last = {}, None, None
        return record

    @property
    def number(self) -> int:
        """The part under way's number: the CNC's part counter, or the gauge's own count."""
        return self._counter if self._counter is not None else self.next_own

    def under_way(self) -> PartRecord | None:
        """The part under way as it stands: each feature fused from its measurements so far
        (``missing`` those not measured yet, the part then ``incomplete``); None when
        nothing of it is measured yet."""
        if not self._values:
            return None
        results = []
        for f in self.job.features:
            got = self._values.get(f.number)
            if not got:
                results.append(FeatureResult(f.number, f.name, f.nominal_mm, None, None, 0,
                                             "missing", f.tol_lower_mm, f.tol_upper_mm))
                continue
            sum_w, sum_wd, n, first = got
            d = first + sum_wd / sum_w
            results.append(FeatureResult(f.number, f.name, f.nominal_mm, d,
                                         1.0 / math.sqrt(sum_w), int(n), judge(f, d),
                                         f.tol_lower_mm, f.tol_upper_mm))
        verdicts = {r.verdict for r in results}
        verdict = "out" if verdicts & {"above", "below"} else \
            "incomplete" if "missing" in verdicts else "ok"
        serial = (f"{self.job.part_number}-{self._counter}" if self._counter is not None
                  else f"{self.job.part_number}-g{self.next_own}")
        return PartRecord(serial, self._started, self.job.part_number, tuple(results), verdict,
                          self.number)
