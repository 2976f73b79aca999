"""The dead time, measured from the gauge's own offsets (pure; time passed in).

Every offset the CNC applies is a step of known size that the gauge itself put into the
process: the measurements after it show it once the parts cut with it reach the gauge. For a
candidate dead time of ``d`` measurements, take each applied step off the measured deviations
from the ``d + 1``-th measurement after it on: what is left is the process alone, which
drifts slowly (wear, heat). With the right ``d`` it has no jumps at the steps; with a wrong
one each step leaves a jump there and one back. The estimate is the ``d`` whose remainder
moves least from measurement to measurement, in absolute differences: one outlier adds the
same two differences whatever ``d`` is, so it cannot move the estimate (squares would let it).

It is taken only from several steps (``MIN_STEPS``) each larger than the measurements'
own scatter, and only when it is clearly better than every other candidate (``MARGIN``),
the typed dead time first of all; until then the typed one stays in use.
"""

from __future__ import annotations

import collections
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

HISTORY = 240
"""Measurements kept (at a part a minute, four hours)."""
MIN_STEPS = 3
"""Applied steps, each above the scatter, that the estimate needs."""
MIN_STEPS_AGAINST = 8
"""... and that it needs to contradict the typed dead time (the prior)."""
MARGIN = 2.0
"""How much better (in scatters) the best candidate must explain the steps than any other."""
MAX_DEAD = 40
"""The longest dead time looked for, measurements."""
PRIOR_SPAN = 3
"""With a typed dead time, candidates up to this many times it (plus as many measurements):
a dead time mis-set by more is not looked for, and a steady cadence of steps has aliases
beyond it that fit almost as well."""


@dataclass(frozen=True)
class DeadTime:
    """A measured dead time: measurements between an offset applied and the first that
    shows it, the same in seconds (the median interval between measurements times it), and
    the steps it rests on."""

    measurements: int
    seconds: float
    steps: int


@dataclass
class DeadTimeEstimator:
    """Measurements and the steps applied between them; ``estimate()`` when they tell."""

    history: int = HISTORY
    deviations: collections.deque = field(default_factory=lambda: collections.deque())
    times: collections.deque = field(default_factory=lambda: collections.deque())
    steps: list[tuple[int, float]] = field(default_factory=list)
    """(measurements taken before it was applied, its effect on the diameter, mm)."""
    taken: int = 0
    """Measurements taken so far (the index of the next one)."""

    def measured(self, deviation_mm: float, time_s: float) -> None:
        """A measurement taken into the process (its deviation from nominal, with every
        offset applied so far in it)."""
        if not math.isfinite(deviation_mm):
            return
        self.deviations.append(deviation_mm)
        self.times.append(time_s)
        self.taken += 1
        while len(self.deviations) > self.history:
            self.deviations.popleft()
            self.times.popleft()
        first = self.taken - len(self.deviations)
        self.steps = [s for s in self.steps if s[0] > first - MAX_DEAD]

    def applied(self, effect_mm: float) -> None:
        """An offset applied now (after the measurements taken so far), of this effect on
        the diameter."""
        if effect_mm != 0.0 and math.isfinite(effect_mm):
            self.steps.append((self.taken, effect_mm))

    def forget(self) -> None:
        """Start again (another process: a reset, a new job)."""
        self.deviations.clear()
        self.times.clear()
        self.steps = []

    def scatter_mm(self) -> float:
        """The measurements' scatter from one to the next (a robust standard deviation of
        one measurement), mm; 0 with fewer than three."""
        y = np.fromiter(self.deviations, float)
        if len(y) < 3:
            return 0.0
        dy = np.diff(y)
        return float(1.4826 * np.median(np.abs(dy - np.median(dy))) / math.sqrt(2.0))

    def costs(self, max_dead: int = MAX_DEAD) -> np.ndarray:
        """For each candidate dead time 0..``max_dead``: how much the process, the steps
        taken off from that many measurements after each on, moves from one measurement to
        the next (sum of absolute differences about their median), mm."""
        y = np.fromiter(self.deviations, float)
        first = self.taken - len(y)
        index = np.arange(first, self.taken)
        out = np.empty(max_dead + 1)
        for d in range(max_dead + 1):
            x = y.copy()
            for at, effect in self.steps:
                x[index >= at + d] -= effect
            dx = np.diff(x)
            out[d] = np.abs(dx - np.median(dx)).sum() if len(dx) else 0.0
        return out

    def estimate(self, prior: int | None = None) -> DeadTime | None:
        """The dead time the steps show, or None while they do not tell it clearly. With a
        ``prior`` (the typed dead time, measurements) that explains the steps within the
        margin of the best, the prior: steps at a steady cadence fit a dead time one cadence
        longer almost as well, and only evidence against the typed one replaces it."""
        scatter = self.scatter_mm()
        if scatter <= 0.0:
            return None
        first = self.taken - len(self.deviations)
        seen = [(at, e) for at, e in self.steps if at >= first + 2]
        # A step needs measurements after it to be seen at all, by at least the candidate.
        max_dead = min(MAX_DEAD, self.taken - (min(at for at, _ in seen) if seen else 0) - 2,
                       MAX_DEAD if prior is None else PRIOR_SPAN * (prior + 1))
        clear = [e for at, e in seen if abs(e) > 2.0 * scatter and at + max_dead < self.taken]
        if len(clear) < MIN_STEPS or max_dead < 1:
            return None
        c = self.costs(max_dead)
        best = int(np.argmin(c))
        if prior is not None and prior <= max_dead and (
                c[prior] - c[best] < MARGIN * scatter or len(clear) < MIN_STEPS_AGAINST):
            best = prior  # the steps do not tell otherwise, or are too few to
        elif np.delete(c, best).min() - c[best] < MARGIN * scatter:
            return None
        t = np.fromiter(self.times, float)
        interval = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
        return DeadTime(best, best * max(interval, 0.0), len(clear))


CONFIRMATIONS = 10
"""Estimates in a row that must agree before a newly measured dead time is taken."""


@dataclass
class MeasuredDeadTime:
    """A controller's measured dead time: the estimator and what it measured, confirmed
    ``CONFIRMATIONS`` times in a row (no flapping), beside the typed one. The law waits the
    typed dead time: on the closed-loop bench, the measured one put in use where it differs
    did not yet hold (CHANGELOG). What is measured is shown, and the log says when it is
    more than a measurement from the typed (a typed time in seconds may hold a fraction of
    an interval the steps cannot resolve)."""

    estimator: DeadTimeEstimator = field(default_factory=DeadTimeEstimator)
    measured_value: DeadTime | None = None
    differs: bool = False
    """Whether the measured dead time is more than a measurement from the typed."""
    _seen: tuple[int, int] = (-1, 0)

    def applied(self, effect_mm: float) -> None:
        """An offset of the gauge's applied now (its effect on the diameter, mm)."""
        self.estimator.applied(effect_mm)

    def typed_measurements(self, typed: int, typed_s: float) -> int:
        """The typed dead time in measurements (seconds at the interval seen)."""
        t = np.fromiter(self.estimator.times, float)
        interval = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
        return max(typed, math.ceil(typed_s / interval - 1e-9) if interval > 0 else 0)

    def measured(self, deviation_mm: float, time_s: float, typed: int, typed_s: float
                 ) -> bool:
        """Take a measurement in; True when the measured dead time came to differ from the
        typed, or to agree with it again (``said`` says how, once)."""
        self.estimator.measured(deviation_mm, time_s)
        prior = self.typed_measurements(typed, typed_s)
        got = self.estimator.estimate(prior)
        now = self.measured_value
        if got is None or (now is not None and got.measurements == now.measurements):
            self._seen = (-1, 0)
            return False
        value, count = self._seen
        self._seen = (got.measurements, count + 1 if value == got.measurements else 1)
        if self._seen[1] < CONFIRMATIONS:
            return False
        self.measured_value, self._seen = got, (-1, 0)
        before, self.differs = self.differs, abs(got.measurements - prior) > 1
        return self.differs != before

    def said(self, typed: int, typed_s: float) -> str:
        """What was measured against the typed, in words an integrator can act on."""
        got = self.measured_value
        if got is None:
            return ""
        typed_text = (f"the typed {self.typed_measurements(typed, typed_s)} "
                      f"(compensation.dead_time_measurements {typed}, dead_time_s {typed_s:g})")
        if not self.differs:
            return (f"dead time measured from {got.steps} of the gauge's offsets: "
                    f"{got.measurements} measurements ({got.seconds:.0f} s), within one of "
                    f"{typed_text} again")
        return (f"dead time measured from {got.steps} of the gauge's offsets: each shows "
                f"{got.measurements} measurements after it is applied ({got.seconds:.0f} s), "
                f"not {typed_text}, which the law waits: set the typed one to the measured, "
                "or find what changed (the part program, the parts between the tool and "
                "the gauge)")

    def status(self, typed_measurements: int, typed_s: float) -> dict[str, Any]:
        """The dead time typed, measured and in use (measurements and seconds), JSON-ready."""
        m = self.measured_value
        typed = {"measurements": typed_measurements, "seconds": typed_s}
        return {"typed": typed, "in_use": typed, "differs": self.differs,
                "measured": None if m is None else {"measurements": m.measurements,
                                                    "seconds": m.seconds, "steps": m.steps}}
