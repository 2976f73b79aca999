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
own scatter, and only when it is clearly better than every other candidate (``MARGIN``);
until then there is none, and the typed dead time stays in use.
"""

from __future__ import annotations

import collections
import math
from dataclasses import dataclass, field

import numpy as np

HISTORY = 240
"""Measurements kept (at a part a minute, four hours)."""
MIN_STEPS = 3
"""Applied steps, each above the scatter, that the estimate needs."""
MARGIN = 2.0
"""How much better (in scatters) the best candidate must explain the steps than any other."""
MAX_DEAD = 40
"""The longest dead time looked for, measurements."""


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

    def estimate(self) -> DeadTime | None:
        """The dead time the steps show, or None while they do not tell it clearly."""
        scatter = self.scatter_mm()
        if scatter <= 0.0:
            return None
        first = self.taken - len(self.deviations)
        seen = [(at, e) for at, e in self.steps if at >= first + 2]
        # A step needs measurements after it to be seen at all, by at least the candidate.
        max_dead = min(MAX_DEAD, self.taken - (min(at for at, _ in seen) if seen else 0) - 2)
        clear = [e for at, e in seen if abs(e) > 2.0 * scatter and at + max_dead < self.taken]
        if len(clear) < MIN_STEPS or max_dead < 1:
            return None
        c = self.costs(max_dead)
        best = int(np.argmin(c))
        others = np.delete(c, best)
        if others.min() - c[best] < MARGIN * scatter:
            return None
        t = np.fromiter(self.times, float)
        interval = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
        return DeadTime(best, best * max(interval, 0.0), len(clear))
