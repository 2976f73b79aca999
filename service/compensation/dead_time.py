"""The dead time, measured from the gauge's own offsets (pure; time passed in).

Every offset the CNC applies is a step of known size that the gauge itself put into the
process: the measurements after it show it once the parts cut with it reach the gauge. For a
candidate dead time of ``d`` measurements, take each applied step off the measured deviations
from the ``d + 1``-th measurement after it on: what is left is the process alone, which
drifts slowly (wear, heat). With the right ``d`` it has no jumps at the steps; with a wrong
one each step leaves a jump there and one back. The estimate is the ``d`` whose remainder
moves least from measurement to measurement, in absolute differences: one outlier adds the
same two differences whatever ``d`` is, so it cannot move the estimate (squares would let it).

The typed dead time stays in use until the steps refute it: the best candidate explains
them clearly better (``MARGIN``) than the typed one and than every candidate between the two
but the best's neighbours, on enough measurements (``MIN_TELLING_AGAINST``) and steps
(``MIN_EDGES_AGAINST``). The typed one is confirmed by several steps (``MIN_STEPS``) each
larger than the measurements' own scatter. A candidate longer than both is no argument
either way: a loop that holds its deviations steady looks, over its last measurements, like
one whose steps have not landed yet. A new value is taken once ``CONFIRMATIONS`` estimates
in a row agree.
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
MIN_EDGES_AGAINST = 4
"""Changes of the offsets applied per measurement, each above twice the scatter and landed
under the best candidate, that a refutation of the typed dead time rests on at least: two
isolated offsets, or a run's two ends and more (a steady run fits any dead time alike in
its middle)."""
MIN_TELLING_AGAINST = 4
"""Measurements that a step lands on under one of the two and not the other, each by more
than twice the scatter, that a refutation of the typed dead time (the prior) needs: two
isolated steps at least."""
MARGIN = 2.5
"""How much better the best candidate must explain the steps than any other: its sum of
absolute differences lower by this many scatters times the root of the number of
measurements where the two differ (they differ only about the steps: the comparison's
noise grows with the steps it rests on, not with the whole history)."""
UNSTEADY = 5.0
"""Intervals between measurements off their median by more than this factor make them
unsteady (``DeadTimeEstimator.steady``): a loaded host's jitter stays within it, a part's
features a second apart and the next part a minute later are far beyond."""
MAX_DEAD = 40
"""The longest dead time looked for, measurements."""
MAD_TO_SIGMA = 1.4826
"""A normal scatter's standard deviation over its median absolute deviation."""
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
    uncertainties: collections.deque = field(default_factory=lambda: collections.deque())
    steps: list[tuple[int, float]] = field(default_factory=list)
    """(measurements taken before it was applied, its effect on the diameter, mm)."""
    taken: int = 0
    """Measurements taken so far (the index of the next one)."""

    def measured(self, deviation_mm: float, time_s: float, uncertainty_mm: float = 0.0
                 ) -> None:
        """A measurement taken into the process (its deviation from nominal, with every
        offset applied so far in it, and its standard uncertainty)."""
        if not math.isfinite(deviation_mm):
            return
        self.deviations.append(deviation_mm)
        self.times.append(time_s)
        self.uncertainties.append(uncertainty_mm if math.isfinite(uncertainty_mm) else 0.0)
        self.taken += 1
        while len(self.deviations) > self.history:
            self.deviations.popleft()
            self.times.popleft()
            self.uncertainties.popleft()
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
        self.uncertainties.clear()
        self.steps = []

    @staticmethod
    def edges(steps: list[tuple[int, float]], ends: bool = False) -> list[tuple[int, float]]:
        """(where, size) of the change each offset makes to the offsets applied a
        measurement: one after a measurement with none changes them by its whole size.
        ``ends``: the measurement after the last of a run of offsets too (none after one)."""
        applied: dict[int, float] = collections.defaultdict(float)
        for at, e in steps:
            applied[at] += e
        where = sorted({*applied, *(at + 1 for at in applied)} if ends else applied)
        return [(at, applied.get(at, 0.0) - applied.get(at - 1, 0.0)) for at in where]

    def scatter_mm(self) -> float:
        """The measurements' scatter from one to the next (a robust standard deviation of
        one measurement), mm; 0 with fewer than three.  Never below their median stated
        uncertainty: a few measurements' median absolute deviation can fall far below the
        scatter, and every margin would shrink with it."""
        y = np.fromiter(self.deviations, float)
        if len(y) < 3:
            return 0.0
        dy = np.diff(y)
        return max(float(MAD_TO_SIGMA * np.median(np.abs(dy - np.median(dy))) / math.sqrt(2.0)),
                   self.stated_mm())

    def stated_mm(self) -> float:
        """The measurements' median stated uncertainty, mm (0 with none)."""
        return float(np.median(np.fromiter(self.uncertainties, float))) \
            if self.uncertainties else 0.0

    def moves(self, max_dead: int = MAX_DEAD) -> np.ndarray:
        """For each candidate dead time 0..``max_dead`` (rows) and each measurement after
        the first (columns): how much the process, the steps taken off from that many
        measurements after each on, moved from the last measurement, mm."""
        y = np.fromiter(self.deviations, float)
        first = self.taken - len(y)
        out = np.tile(np.diff(y), (max_dead + 1, 1))
        if not self.steps or out.shape[1] == 0:
            return out
        at = np.array([a for a, _ in self.steps]) - first
        effect = np.array([e for _, e in self.steps])
        for d in range(max_dead + 1):
            # A step landing at measurement j moves the process between j - 1 and j.
            j = at + d - 1
            inside = (j >= 0) & (j < out.shape[1])
            np.subtract.at(out[d], j[inside], effect[inside])
        return out

    @staticmethod
    def roughness(moves: np.ndarray) -> np.ndarray:
        """``moves`` as absolute differences about each candidate's median move (the
        process's drift: wear), mm."""
        if moves.shape[1] == 0:
            return moves
        return np.abs(moves - np.median(moves, axis=1, keepdims=True))

    def steady(self) -> bool:
        """Whether the measurements come at a steady rate (eight intervals in ten within a
        factor ``UNSTEADY`` of the median): only then is a dead time a fixed count of them.
        Where a part's features are measured a second apart and the next part a minute
        later, or some are skipped, the count varies from offset to offset, and no single
        count refutes the typed one (it fitted none: a job of two tools measured 0 for 2)."""
        t = np.fromiter(self.times, float)
        if len(t) < 3:
            return False
        gaps = np.diff(t)
        median = float(np.median(gaps))
        low, high = np.quantile(gaps, [0.1, 0.9])
        return median > 0 and low * UNSTEADY >= median and high <= UNSTEADY * median

    def interval_s(self) -> float:
        """The median interval between the measurements kept, s; 0 with fewer than two."""
        t = np.fromiter(self.times, float)
        return float(np.median(np.diff(t))) if len(t) > 1 else 0.0

    def estimate(self, prior: int | None = None) -> DeadTime | None:
        """The dead time the steps show, or None while they do not tell it clearly. With a
        ``prior`` (the typed dead time, measurements): the best candidate where the steps
        refute the prior (see the module's docstring), else the prior once enough clear steps
        confirm it (steps at a steady cadence fit a dead time one cadence longer almost as
        well: only evidence against the typed one replaces it)."""
        first = self.taken - len(self.deviations)
        seen = [(at, e) for at, e in self.steps if at >= first + 2]
        scatter = self.scatter_mm() if seen else 0.0  # no step, nothing to tell: none
        if scatter <= 0.0:
            return None
        # A step needs measurements after it to be seen at all, by at least the candidate.
        max_dead = min(MAX_DEAD, self.taken - (min(at for at, _ in seen) if seen else 0) - 2,
                       MAX_DEAD if prior is None else PRIOR_SPAN * (prior + 1))
        if max_dead < 1 or (prior is not None and prior > max_dead):
            return None  # no step old enough to show the typed dead time: none tells
        moves = self.moves(max_dead)
        r = self.roughness(moves)
        c = r.sum(axis=1)
        best = int(np.argmin(c))
        # The scatter of the process the best candidate leaves, the gauge's own steps taken
        # off: a loop that oscillates on a wrong dead time swings its raw measurements by its
        # offsets, which is no noise to judge the steps against.
        scatter = min(scatter, max(MAD_TO_SIGMA * float(np.median(r[best])) / math.sqrt(2.0),
                                   self.stated_mm()))
        if scatter <= 0.0:
            return None

        def clearly_worse(d: int) -> bool:
            """Whether candidate ``d`` explains the steps worse than the best beyond noise."""
            diff = r[d] - r[best]
            differ = int(np.count_nonzero(np.abs(moves[d] - moves[best]) > 1e-12))
            return d != best and diff.sum() > MARGIN * scatter * math.sqrt(differ)

        def telling(d: int) -> int:
            """Measurements where candidate ``d`` and the best differ by more than twice the
            scatter: each is a landing one of them puts where the other does not."""
            return int(np.count_nonzero(np.abs(moves[d] - moves[best]) > 2.0 * scatter))

        # The steps that tell: where the offsets applied change by more than the scatter
        # from one measurement to the next (a steady stream of equal offsets, a ramp, fits
        # any dead time alike), and shown by the best candidate (a step too recent to have
        # landed counts against no candidate).
        clear = [e for at, e in self.edges(seen) if abs(e) > 2.0 * scatter
                 and at + best < self.taken]
        # Where the offsets applied per measurement change, ends of runs included, landed
        # under the best: what the refutation rests on.
        landed = [e for at, e in self.edges(seen, ends=True) if abs(e) > 2.0 * scatter
                  and at + best < self.taken]
        if prior is not None and self.steady() and clearly_worse(prior) \
                and len(landed) >= MIN_EDGES_AGAINST \
                and telling(prior) >= MIN_TELLING_AGAINST and all(map(
                    clearly_worse, range(best + 2, prior + 1) if best < prior
                    else range(prior, best - 1))):
            # The steps refute the typed one and every candidate between it and the best
            # but the best's neighbour: the best replaces it (the loop swings on the typed
            # one meanwhile; the next steps tell the neighbours apart). One longer than both
            # is no argument for the typed one: a loop that holds its deviations steady
            # looks, over its last few measurements, like one whose steps never landed.
            return DeadTime(best, best * max(self.interval_s(), 0.0),
                            max(len(clear), len(landed) // 2))
        if len(clear) < MIN_STEPS:
            return None
        if prior is not None:
            best = prior  # the steps do not tell otherwise, or are too few to
        elif not all(clearly_worse(d) for d in range(max_dead + 1) if d != best):
            return None
        return DeadTime(best, best * max(self.interval_s(), 0.0), len(clear))


CONFIRMATIONS = 2
"""Estimates in a row that must agree before a newly measured dead time is taken."""
DRIFT_SPAN = 30
"""The measurements the process's drift is taken over when a measured dead time is put in
use (wear may change its rate over an insert's life)."""


@dataclass
class MeasuredDeadTime:
    """A controller's measured dead time: the estimator and what it measured, confirmed
    ``CONFIRMATIONS`` times in a row (no flapping), beside the typed one. The law waits the
    measured one once it is confirmed and differs from the typed (``in_use``), the typed one
    until then; the log says when it is more than a measurement from the typed (a typed time
    in seconds may hold a fraction of an interval the steps cannot resolve)."""

    estimator: DeadTimeEstimator = field(default_factory=DeadTimeEstimator)
    measured_value: DeadTime | None = None
    differs: bool = False
    """Whether the measured dead time is more than a measurement from the typed."""
    use_measured: bool = False
    """Whether the law waits the measured one: decided when it is confirmed (never by the
    rate of measurements meanwhile), any difference where the typed one is in measurements,
    more than one where it is in seconds (they fall on a measurement either way)."""
    _seen: tuple[int, int] = (-1, 0)
    _interval: float = 0.0

    def applied(self, effect_mm: float) -> None:
        """An offset of the gauge's applied now (its effect on the diameter, mm)."""
        self.estimator.applied(effect_mm)

    def typed_measurements(self, typed: int, typed_s: float) -> int:
        """The typed dead time in measurements (seconds at the interval seen: the last one
        known when the estimator starts again)."""
        if len(self.estimator.times) > 1:
            self._interval = self.estimator.interval_s()
        interval = self._interval
        return max(typed, math.ceil(typed_s / interval - 1e-9) if interval > 0 else 0)

    def measured(self, deviation_mm: float, time_s: float, typed: int, typed_s: float,
                 uncertainty_mm: float = 0.0) -> bool:
        """Take a measurement in (its standard uncertainty: the scatter is never taken
        below it); True when the measured dead time came to differ from the typed, or to
        agree with it again (``said`` says how, once)."""
        self.estimator.measured(deviation_mm, time_s, uncertainty_mm)
        prior = self.typed_measurements(typed, typed_s)
        # What the steps must tell against: the dead time in use (a measured one stays
        # until the steps say otherwise as clearly as they said it).
        got = self.estimator.estimate(prior if self.measured_value is None
                                      else self.measured_value.measurements)
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
        self.use_measured = self.differs or (typed_s <= 0 and got.measurements != prior)
        return self.differs != before

    def drift_mm(self) -> float | None:
        """The process's move per measurement under the measured dead time, the gauge's
        steps taken off: the Theil-Sen slope of the last ``DRIFT_SPAN`` measurements (the
        median of every pair's slope: a tenth of the median move's noise over 20 of them,
        and one outlier cannot tilt it), mm; None before one is measured."""
        m = self.measured_value
        if m is None or len(self.estimator.deviations) < 3:
            return None
        moves = self.estimator.moves(m.measurements)[m.measurements][-DRIFT_SPAN:]
        process = np.concatenate(([0.0], np.cumsum(moves)))
        i, j = np.triu_indices(len(process), k=1)
        return float(np.median((process[j] - process[i]) / (j - i)))

    def in_use(self, typed: int, typed_s: float) -> tuple[int, float]:
        """The dead time the law waits (measurements, seconds): the measured one where it
        was found to differ from the typed when it was confirmed (``use_measured``), else the
        typed one. Typed in seconds, the measured one is in seconds too: a rate of
        measurements that changes (a busy host) changes how many measurements the same
        seconds are."""
        m = self.measured_value
        if m is None or not self.use_measured:
            return typed, typed_s
        return (0, m.seconds) if typed_s > 0 else (m.measurements, 0.0)

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
                f"not {typed_text}; the law now waits the measured one. Set the typed one to "
                "it, or find what changed (the part program, the parts between the tool and "
                "the gauge)")

    def status(self, typed_measurements: int, typed_s: float) -> dict[str, Any]:
        """The dead time typed, measured and in use (measurements and seconds), JSON-ready."""
        m = self.measured_value
        typed = {"measurements": typed_measurements, "seconds": typed_s}
        use_m, use_s = self.in_use(typed_measurements, typed_s)
        return {"typed": typed, "in_use": {"measurements": use_m, "seconds": use_s},
                "differs": self.differs,
                "measured": None if m is None else {"measurements": m.measurements,
                                                    "seconds": m.seconds, "steps": m.steps}}
