"""The controller's two laws: the measuring cycle's window (``WindowLaw``) and the predictive
run-to-run law (``Predictor``): the process as the gauge sees it without compensation,
filtered by a robust double exponentially weighted moving average, corrected with the offsets
that are applied but not visible yet.

The window law waits out the dead time after each correction, fills a window of good
measurements and corrects a share (``gain``) of its median or weighted mean: simple, and slow
(a correction every dead time plus a window).

A correction acts only on what is cut after it, and the gauge sees that ``d`` measurements
later (the laser behind the tool, or the part measured after the next ones were cut).
Correcting a share ``g`` of each measured deviation as it comes is a delayed integrator, which
oscillates unless ``g < 2 sin(pi / (2 (2 d + 1)))`` (0.62 at d = 2). Instead, each measurement
is tagged with the offsets in force when its surface was cut: the *uncompensated* process is

    u = deviation - (effect of the offsets applied) + (effect of those still in flight),

which no correction moves, so filtering it cannot chase its own corrections. Its level ``L``
and trend ``T`` follow Holt's double EWMA (``L <- lam u + (1 - lam)(L + T)``,
``T <- beta (L' - L) + (1 - beta) T``; Butler and Stefani's predictor-corrector: a single
EWMA leaves a steady lag under linear wear), and the next correction sets the total effect to
``-(L + h T)``, the process forecast ``h = d + 1`` measurements ahead, where the correction
will be seen. Stable for ``0 < lam <= 1`` at any dead time the tagging knows
(Ingolfsson and Sachs: ``0 < lam xi < 2`` for a model gain ``xi``).

Robust: a measurement that the process's own scatter does not explain (beyond the mean-value
band: four times the robust scale of the one-step surprises, estimated from the data) is set
aside. Alone, it was an outlier and never moves the estimate; confirmed by the next one on the
same side, it was a step (a chipped or new insert, a machine that cooled) and the level jumps
to it at once, the trend kept. Inside the band the estimate moves by the median of the last
three surprises, so one measurement alone, however far off, never moves it, and heavy tails
move it little. The process starts from two measurements that agree
(or three on a line), never from one.

Where a step is expected, the first part cut after it sets the level: after a reset or a
change of the CNC's total by someone else (an insert change; meanwhile the parts being cut are
forecast where the last new insert stood, so what the zeroed wear offset loses, the machine's
growth, is corrected before it is seen), and after a stop (a gap of ten intervals between
measurements: the machine may have cooled).

The null band is never narrower than the forecast's own noise (one of its standard
deviations: the scale times the filter's noise gain), and an offset that would reverse the
last one needs three null bands: what the estimate cannot tell from noise is not corrected.
The gains are per dead-time cycle: where the dead time in seconds spans several measurements
(continuous cutting), each takes its share.

The gains follow the process (``gain_share``): the settings' ``gain`` and ``trend_gain`` are
the most, taken whole where the process moves over a dead-time cycle by two of its scatters
or more, down to 0.4 of them where it hardly moves against its scatter (a tight tolerance
with a noisy gauge: there a gain follows noise, not the process).

The bound as applied: the level's gain stays in ``[0.4 gain, gain]`` with ``0 < gain <= 1``,
inside Ingolfsson and Sachs' ``0 < lam xi < 2`` for any model gain ``0 < xi <= 1`` (the CNC
applies what is written: ``xi = 1`` when the offset's convention is right). It holds for the
dead time the tagging knows: the one the gauge's own offsets show once measured
(``service.compensation.dead_time``), the typed one until then; a typed one twice too long
can swing the loop until the measured one is in use.

Pure: deviations and effects in mm of diameter, time passed in.
"""

from __future__ import annotations

import collections
import itertools
import math
import statistics
from dataclasses import dataclass, field, replace
from typing import Any, Protocol

from service.compensation.dead_time import MAD_TO_SIGMA

REVERSAL_NULL_BANDS = 3.0
"""An offset that would reverse the last one needs this many null bands (predictive law)."""


@dataclass(frozen=True)
class Hold:
    """A law has nothing to correct from now: ``code`` (a stable name, ``dead_time``,
    ``starting``, ``set_aside`` ...) and ``why`` in words."""

    code: str
    why: str


@dataclass(frozen=True)
class Estimate:
    """What a law makes of the measurements so far.

    Attributes
    ----------
    deviation_mm : float
        Where the coming parts stand with the offsets in force and in flight (mm of
        diameter; the controller corrects ``-gain`` times it).
    gain : float
        The share of it to correct.
    null_mm : float
        Nothing is corrected inside this.
    note : str
        What the law followed (a step), for the decision's words.
    """

    deviation_mm: float
    gain: float
    null_mm: float
    note: str = ""


class Law(Protocol):
    """A control law, chosen once for the settings (``law_of``): the controller tells it each
    measurement's deviation and what it applies, and asks for an estimate or a hold."""

    def estimate(self, deviation_mm: float, uncertainty_mm: float, now_s: float,
                 time_s: float, applied_mm: float, last_offset_mm: float,
                 deadband_mm: float) -> Estimate | Hold:
        """The estimate from this measurement on, or why there is none now."""
        ...

    def applied(self, effect_mm: float, now_s: float) -> None:
        """An offset's effect on the diameter (mm), applied now."""
        ...

    def clear(self) -> None:
        """The controller changed state: what was gathered for the next correction goes."""
        ...

    def restart(self, now_s: float) -> None:
        """A step is expected (a reset, a change at the CNC): the parts cut before now say
        nothing of the process after."""
        ...

    def retuned(self, settings: Any, renewed: bool) -> Law:
        """The law under new settings of the same law; ``renewed``: another nominal or
        offset convention, the process estimate starts again."""
        ...

    def use_dead_time(self, measurements: int, seconds: float,
                      drift_mm: float | None = None) -> None:
        """Wait this dead time from now on (the offsets in flight included); ``drift_mm``:
        the process's move per measurement as the steps show it under that dead time, when
        it was measured (what was estimated under the other is not kept)."""
        ...


def filtered_deviation(window: list[tuple[float, float]], how: str) -> float:
    """The window of (deviation, uncertainty) as one deviation: the median, or the mean
    weighted by 1 / uncertainty^2."""
    devs = [d for d, _ in window]
    if how == "median":
        return float(statistics.median(devs))
    weights = [1.0 / u**2 for _, u in window]
    return float(sum(w * d for w, d in zip(weights, devs, strict=True)) / sum(weights))


@dataclass
class WindowLaw:
    """The measuring cycle's window: the measurements after a correction within both dead
    times are not taken (they were cut before it); then ``size`` good ones make one filtered
    deviation (``how``: 'median' or 'mean')."""

    size: int
    how: str
    dead_measurements: int
    dead_s: float
    values: collections.deque = field(default_factory=collections.deque)
    since_correction: int = 0
    correction_time: float = -math.inf
    gain: float = 1.0
    """The share of the filtered deviation corrected."""

    @classmethod
    def of(cls, settings: Any) -> WindowLaw:
        """For compensation settings (``window``, ``filter``, the dead times, ``gain``); no
        dead time at the start."""
        return cls(settings.window, settings.filter, settings.dead_time_measurements,
                   settings.dead_time_s, collections.deque(maxlen=settings.window),
                   settings.dead_time_measurements, gain=settings.gain)

    def retuned(self, settings: Any, renewed: bool = False) -> WindowLaw:
        """An empty window for new settings, the dead time running on."""
        return replace(WindowLaw.of(settings), since_correction=self.since_correction,
                       correction_time=self.correction_time)

    def estimate(self, deviation_mm: float, uncertainty_mm: float, now_s: float,
                 time_s: float, applied_mm: float, last_offset_mm: float,
                 deadband_mm: float) -> Estimate | Hold:
        """The window's filtered deviation once full, outside the dead time."""
        got = self.observe(deviation_mm, uncertainty_mm, now_s)
        return Hold(*got) if isinstance(got, tuple) else Estimate(got, self.gain, deadband_mm)

    def applied(self, effect_mm: float, now_s: float) -> None:
        """An offset applied now: its dead time starts."""
        self.corrected(now_s)

    def restart(self, now_s: float) -> None:
        """Nothing more than the dead time its ``applied`` started."""

    def use_dead_time(self, measurements: int, seconds: float,
                      drift_mm: float | None = None) -> None:
        """Wait this dead time after a correction."""
        self.dead_measurements, self.dead_s = measurements, seconds

    def observe(self, deviation: float, uncertainty: float, now: float
                ) -> float | tuple[str, str]:
        """The filtered deviation, or (code, why) it is held."""
        self.since_correction += 1
        if self.since_correction <= self.dead_measurements \
                or now - self.correction_time < self.dead_s:
            return "dead_time", "dead time after a correction"
        self.values.append((deviation, max(uncertainty, 1e-6)))
        if len(self.values) < self.size:
            return "filling_window", f"filling the window ({len(self.values)} of {self.size})"
        return filtered_deviation(list(self.values), self.how)

    def corrected(self, now: float) -> None:
        """An offset was applied now: the dead time starts."""
        self.since_correction, self.correction_time = 0, now

    def clear(self) -> None:
        """Start the window afresh."""
        self.values.clear()


@dataclass
class InFlight:
    """An offset applied whose effect the gauge has not seen yet."""

    effect_mm: float
    after_measurements: int   # it shows from the measurement after this many
    visible_at_s: float       # ... and not before this time
    seen: int = 0             # measurements since it was applied
    applied_s: float = -math.inf

    def visible(self, now_s: float) -> bool:
        """Whether the measurement taken now shows it."""
        return self.seen > self.after_measurements and now_s >= self.visible_at_s


BAND_SCALES = 4.0
"""The mean-value band, in robust scales of the one-step surprise: a Gaussian surprise
leaves it once in 16 000; a 15 um outlier among 2.5 um of scatter does not fit in it."""
LAG_RUN = 8
"""Surprises in a row on one side that say the estimate trails the process."""
MEDIAN_OF = 3
"""Inside the band the estimate moves by the median of the last three surprises: one
measurement alone, however far off, never moves it (but the first two after a new level)."""
SCALE_MEMORY = 0.05
"""The scale's own EWMA weight once it has 20 surprises (1 / n before: the mean)."""
STOP_INTERVALS = 10.0
STOP_MIN_S = 60.0
"""A gap between measurements this many intervals long, and a minute at least, is a stop
(the machine may have cooled; a busy host's second is not one)."""
NULL_SIGMAS = 1.0
"""The null band is at least this many standard deviations of the forecast's own noise."""
FULL_GAIN_SCATTERS = 2.0
MIN_GAIN_SHARE = 0.4
MOVE_SPAN = 10
"""The gains follow the process (``gain_share``): the whole where it moves by two
scatters over a dead-time cycle, 0.4 of them at the least, from the last two spans of ten
measurements (or of a dead-time cycle, where that is longer)."""
ABS_TO_SIGMA = math.sqrt(math.pi / 2.0)
"""The mean absolute value of a Gaussian is sigma / this."""


def gain_share(values: list[float], h: int) -> float:
    """The share of the settings' gains a process asks for, from its uncompensated
    ``values`` (mm) and ``h`` measurements to a correction showing: the whole where it moves
    over a dead-time cycle by ``FULL_GAIN_SCATTERS`` of its scatter or more, down to
    ``MIN_GAIN_SHARE`` where it hardly moves against its scatter (a tight tolerance measured
    by a noisy gauge: there a gain follows noise, not the process). Both from the values
    themselves, not from the estimate the gains make: a gain cut by a trend not learnt yet,
    or by a scatter the lag inflates, would never catch up (continuous cutting at 5 um/min
    lost its Cpk so)."""
    span = max(h, MOVE_SPAN)
    if len(values) < 2 * span:
        return 1.0
    values = values[-2 * span:]
    steps = [b - a for a, b in itertools.pairwise(values)]
    mid = statistics.median(steps)
    scatter = MAD_TO_SIGMA * statistics.median(abs(d - mid) for d in steps) / math.sqrt(2.0)
    if scatter <= 0.0:
        return 1.0
    moved = abs(statistics.median(values[span:]) - statistics.median(values[:span]))
    return min(1.0, max(MIN_GAIN_SHARE, moved * h / span / scatter / FULL_GAIN_SCATTERS))


@dataclass
class Predictor:
    """Level and trend of the uncompensated process, its scatter, and the offsets in flight.

    Attributes
    ----------
    gain : float
        ``lam``, the share of each measurement taken into the level (feedback).
    trend_gain : float
        ``beta``, the share of each level change taken into the trend (0: a single EWMA).
    horizon : int
        How many measurements ahead the forecast looks at least (dead time in measurements
        + 1).
    dead_s : float
        The dead time in seconds: the forecast looks as many measurements ahead as come in
        it (at the interval between measurements as seen), + 1, when that is more.
    band_mm : float
        The mean-value band: a surprise beyond it is set aside until the next measurement
        says outlier or step (0: ``BAND_SCALES`` robust scales, from the data).
    floor_mm : float
        The band is never narrower than this (the null band: a surprise that would not be
        corrected anyway need not be doubted).
    """

    gain: float
    trend_gain: float
    horizon: int
    band_mm: float = 0.0
    floor_mm: float = 0.0
    dead_s: float = 0.0
    level: float | None = None
    trend: float = 0.0
    scale: float | None = None
    surprises: int = 0
    in_flight: list[InFlight] = field(default_factory=list)
    aside: float | None = None
    """The uncompensated value set aside (a surprise beyond the band), waiting for the next
    measurement to say outlier or step."""
    starting: list[float] = field(default_factory=list)
    """The uncompensated values so far while the level is not known."""
    skip: InFlight | None = None
    """After a reset: measurements cut before it (while this is not visible) are not taken."""
    last_step_mm: float | None = None
    """The step the last measurement confirmed (mm), or None."""
    expected: str = ""
    """A step is expected: ``insert`` (a reset, a change at the CNC) or ``stop``; the next
    measurement taken starts the level."""
    fresh_level: float | None = None
    """The process as the first part after the last reset or change at the CNC showed it
    (a new insert on a machine as warm as it then was)."""
    interval_s: float | None = None
    """The time between measurements, as seen (an EWMA)."""
    last_s: float | None = None
    surprise_run: collections.deque = field(
        default_factory=lambda: collections.deque(maxlen=MEDIAN_OF))
    """The last surprises inside the band (a step or a new level starts it afresh)."""
    lag_run: list[float] = field(default_factory=list)
    """The last surprises, while they fall on one side."""
    recent: collections.deque = field(default_factory=lambda: collections.deque(maxlen=400))
    """The uncompensated values taken lately (how far the process moves, against what
    scatter)."""
    _response: tuple | None = field(default=None, repr=False, compare=False)
    _share: tuple | None = field(default=None, repr=False, compare=False)

    @classmethod
    def of(cls, settings: Any) -> Predictor:
        """A fresh predictor for compensation settings (``gain``, ``trend_gain``,
        ``dead_time_measurements``, ``mean_value_band_mm``, ``deadband_mm``)."""
        return cls(settings.gain, settings.trend_gain, settings.dead_time_measurements + 1,
                   settings.mean_value_band_mm, settings.deadband_mm, settings.dead_time_s)

    def retuned(self, settings: Any) -> Predictor:
        """This predictor (its estimate, scatter and offsets in flight) with new settings'
        gains, bands and dead time."""
        fresh = Predictor.of(settings)
        return replace(self, gain=fresh.gain, trend_gain=fresh.trend_gain,
                       horizon=fresh.horizon, band_mm=fresh.band_mm, floor_mm=fresh.floor_mm,
                       dead_s=fresh.dead_s)

    def applied(self, effect_mm: float, after_measurements: int, visible_at_s: float,
                applied_s: float = -math.inf) -> None:
        """An offset was applied (by the gauge, or by someone else at the CNC) at
        ``applied_s``: its effect on the diameter (mm) shows from the measurement after
        ``after_measurements`` more, at ``visible_at_s`` at the earliest."""
        self.in_flight.append(InFlight(effect_mm, after_measurements, visible_at_s,
                                       applied_s=applied_s))

    def use_dead_time(self, measurements: int, seconds: float,
                      drift_mm: float | None = None) -> None:
        """Another dead time from now on (the horizon; when the offsets in flight show).
        With ``drift_mm`` (it was measured): the trend is that drift, the next measurement
        sets the level (a loop that swung on a wrong dead time left a trend of its swings)."""
        self.horizon, self.dead_s = measurements + 1, seconds
        if drift_mm is not None and self.level is not None and self.skip is None:
            self.trend, self.level, self.expected = drift_mm, None, "stop"
            self.aside, self.starting, self.lag_run = None, [], []
            self.surprise_run.clear()
        for f in [*self.in_flight, *([self.skip] if self.skip else [])]:
            f.after_measurements = measurements
            f.visible_at_s = f.applied_s + seconds

    def in_flight_mm(self) -> float:
        """The effect of the offsets not yet visible, mm of diameter."""
        return sum(f.effect_mm for f in self.in_flight)

    def band(self, uncertainty_mm: float = 0.0) -> float:
        """The mean-value band now (mm): the setting, or ``BAND_SCALES`` scales of the
        surprises seen (the measurement's own uncertainty before there are any)."""
        if self.band_mm > 0:
            return self.band_mm
        scale = self.scale if self.scale is not None else uncertainty_mm * math.sqrt(2.0)
        return max(BAND_SCALES * max(scale, uncertainty_mm), self.floor_mm)

    def observe(self, deviation_mm: float, applied_mm: float, now_s: float,
                uncertainty_mm: float = 0.0, taken_s: float | None = None
                ) -> float | tuple[str, str]:
        """Take a measurement's deviation from nominal, with ``applied_mm`` the effect of all
        offsets applied so far (``uncertainty_mm`` its standard uncertainty, ``taken_s`` when
        it was taken: the interval between measurements; ``now_s`` when it is judged);
        return the forecast of the uncompensated process ``horizon`` measurements ahead
        (mm), or (code, why) nothing is forecast on this measurement's word."""
        self.last_step_mm = None
        self._clock(now_s if taken_s is None else taken_s)
        for f in [*self.in_flight, *([self.skip] if self.skip else [])]:
            f.seen += 1
        self.in_flight = [f for f in self.in_flight if not f.visible(now_s)]
        if self.skip is not None:
            if not self.skip.visible(now_s):
                if self.level is not None:  # a new insert's level, as the last one's
                    return self.forecast()
                return "cut_before_reset", "cut before the reset: not taken"
            self.skip = None
            self.level = None
        u = deviation_mm - applied_mm + self.in_flight_mm()
        band = self.band(uncertainty_mm)
        if self.level is None:
            return self._start(u, band)
        before = self.level
        surprise = u - (before + self.trend)
        self._learn_scale(surprise, band, uncertainty_mm)
        if abs(surprise) > band:
            if self.aside is not None and (self.aside - before) * surprise > 0 \
                    and abs(u - (self.aside + self.trend)) <= band:
                # Confirmed: a step. The level jumps to the two; the trend stays the wear's.
                self.level, self.aside = 0.5 * (u + self.aside + self.trend), None
                self.surprise_run.clear()
                self.lag_run = []
                self.last_step_mm = self.level - before
                return self.forecast()
            self.aside = u
            self.level = before + self.trend  # as if this measurement had not come
            return "set_aside", (f"{surprise * 1000:+.1f} um from the process estimate, "
                                 f"beyond the mean-value band of {band * 1000:.1f} um: set "
                                 "aside until the next measurement says outlier or step")
        self.aside = None
        self.recent.append(u)
        self.surprise_run.append(surprise)
        counted = statistics.median(self.surprise_run)
        if self._lagging(surprise):  # the estimate trails the process: catch it up
            self.level, self.lag_run = before + self.trend + statistics.median(self.lag_run), []
            return self.forecast()
        lam, beta = self.gains()
        self.level = before + self.trend + lam * counted
        self.trend = beta * (self.level - before) + (1.0 - beta) * self.trend
        return self.forecast()

    def forecast(self) -> float:
        """The uncompensated process ``steps_ahead()`` measurements ahead (mm)."""
        assert self.level is not None
        return self.level + self.steps_ahead() * self.trend

    def steps_ahead(self) -> int:
        """How many measurements ahead the next correction will show."""
        if self.dead_s <= 0 or not self.interval_s:
            return self.horizon
        return max(self.horizon, math.ceil(self.dead_s / self.interval_s - 1e-9) + 1)

    def null_band(self) -> float:
        """The null band in force (mm): the setting (``floor_mm``), or the forecast's own
        scatter where that is wider (``NULL_SIGMAS`` of it): what the estimate cannot tell
        from noise is not corrected (Siemens' _TZL, set from the data)."""
        if self.scale is None:
            return self.floor_mm
        return max(self.floor_mm, NULL_SIGMAS * self.scale * self.noise_gain())

    def gains(self) -> tuple[float, float]:
        """``gain`` and ``trend_gain`` per measurement. They are per dead-time cycle: where
        the dead time in seconds spans more measurements than the dead time in measurements
        (continuous cutting, a fused diameter every few seconds), each measurement takes the
        share that makes the same over the cycle."""
        per_cycle = self.steps_ahead() / self.horizon
        share = self.share()
        gain, trend_gain = self.gain * share, self.trend_gain * share
        if per_cycle <= 1.0:
            return gain, trend_gain
        return (1.0 - (1.0 - gain) ** (1.0 / per_cycle),
                1.0 - (1.0 - trend_gain) ** (1.0 / per_cycle))

    def share(self) -> float:
        """The share of the settings' gains the process asks for now (``gain_share``)."""
        h = self.steps_ahead()
        key = (len(self.recent), self.recent[-1] if self.recent else None, h)
        if self._share is None or self._share[0] != key:
            self._share = (key, gain_share(list(self.recent), h))
        return self._share[1]

    def noise_gain(self) -> float:
        """How much of the measurements' scatter (one scale) reaches the forecast: the root
        sum of squares of the filter's weights."""
        return math.sqrt(sum(r * r for r in self.response()))

    def response(self) -> list[float]:
        """The forecast's response to a unit surprise, measurement by measurement after it
        (the process itself unchanged): the filter's weights."""
        lam, beta = self.gains()
        key = (lam, beta, self.steps_ahead())
        if self._response is None or self._response[0] != key:
            h, level, trend, out = key[2], lam, beta * lam, []
            for _ in range(round(20 / lam)):
                out.append(level + h * trend)
                new = (1.0 - lam) * (level + trend)
                trend = beta * (new - level) + (1.0 - beta) * trend
                level = new
            self._response = (key, out)
        return self._response[1]

    def _clock(self, now_s: float) -> None:
        """The interval between measurements, as they come (a stop does not count)."""
        if self.last_s is not None and now_s > self.last_s:
            gap = now_s - self.last_s
            if self.interval_s is None:
                self.interval_s = gap
            elif gap < STOP_INTERVALS * self.interval_s:
                self.interval_s += 0.1 * (gap - self.interval_s)
            elif self.level is not None and self.skip is None and gap >= STOP_MIN_S:
                # A stop: the machine may have cooled. The first part cut after it sets the
                # level (the parts measured meanwhile were cut before it).
                self.skip = InFlight(0.0, self.horizon - 1, -math.inf)
                self.expected = "stop"
        self.last_s = now_s

    def _start(self, u: float, band: float) -> float | tuple[str, str]:
        """The process starts from the latest of two measurements that agree, or of three on
        a line (a tool that wears fast), never from one; but after a reset or a change at the
        CNC (a new insert: a step is expected) from the first part cut after it."""
        if self.expected:
            if self.expected == "insert":
                self.fresh_level = u
            self.level, self.starting, self.expected = u, [], ""
            return self.forecast()
        seen = [*self.starting[-2:], u]
        if len(seen) >= 2 and abs(seen[-1] - seen[-2]) <= band:
            self.level, self.starting = u, []
            return self.forecast()
        if len(seen) == 3 and abs(seen[2] - 2 * seen[1] + seen[0]) <= band:
            self.level, self.starting = u, []
            if self.trend_gain > 0:  # a single EWMA (no trend) stays one
                self.trend = 0.5 * (seen[2] - seen[0])
            return self.forecast()
        self.starting = seen
        return "starting", ("the process estimate starts from two measurements that agree "
                            f"within {band * 1000:.1f} um, or three on a line: waiting for "
                            "the next")

    def _scale(self) -> float:
        return self.scale if self.scale is not None else 0.0

    def _lagging(self, surprise: float) -> bool:
        """Whether the last ``LAG_RUN`` surprises all fell on one side, by more than the
        scatter and the null band at their median: a process that moves faster than the
        estimate follows (a fast warm-up), not noise (one such run in 128 by chance, and then
        seldom beyond the scatter)."""
        if self.lag_run and self.lag_run[-1] * surprise <= 0:
            self.lag_run = []
        self.lag_run.append(surprise)
        return len(self.lag_run) >= LAG_RUN and abs(statistics.median(self.lag_run)) > max(
            self._scale(), self.null_band())

    def _learn_scale(self, surprise: float, band: float, uncertainty_mm: float) -> None:
        """The robust scale of the surprises: an EWMA of their size, each clipped to the
        band (an outlier widens it by little), never below the measurement's uncertainty."""
        self.surprises += 1
        weight = max(1.0 / self.surprises, SCALE_MEMORY)
        size = ABS_TO_SIGMA * min(abs(surprise), band)
        old = self.scale if self.scale is not None else size
        self.scale = max(old + weight * (size - old), uncertainty_mm)

    def reset(self, after_measurements: int = 0, visible_at_s: float = -math.inf) -> None:
        """A reset (a new insert): the measurements cut before it (the next
        ``after_measurements``, and those before ``visible_at_s``) are not taken, then the
        level starts afresh from the first after them; the trend, the insert's wear per
        measurement, is kept (the same cut wears the next insert alike), and so is the
        scatter. Meanwhile the parts being cut are forecast where the last new insert's
        stood (``fresh_level``), when there was one: what an insert change loses (the wear
        offset zeroed with the machine's growth in it) is corrected before it is seen."""
        self.level, self.aside, self.starting = self.fresh_level, None, []
        self.expected, self.lag_run = "insert", []
        self.surprise_run.clear()
        self.skip = InFlight(0.0, after_measurements, visible_at_s,
                             applied_s=visible_at_s - self.dead_s) \
            if after_measurements > 0 or visible_at_s > -math.inf else None


@dataclass
class PredictiveLaw:
    """The predictive law (``Predictor``) with the dead times its offsets take to show."""

    predictor: Predictor
    dead_measurements: int
    dead_s: float

    @classmethod
    def of(cls, settings: Any) -> PredictiveLaw:
        """A fresh estimate for compensation settings."""
        return cls(Predictor.of(settings), settings.dead_time_measurements,
                   settings.dead_time_s)

    def retuned(self, settings: Any, renewed: bool = False) -> PredictiveLaw:
        """New gains and bands, the estimate kept (``renewed``: started again)."""
        if renewed:
            return PredictiveLaw.of(settings)
        return PredictiveLaw(self.predictor.retuned(settings), settings.dead_time_measurements,
                             settings.dead_time_s)

    def estimate(self, deviation_mm: float, uncertainty_mm: float, now_s: float,
                 time_s: float, applied_mm: float, last_offset_mm: float,
                 deadband_mm: float) -> Estimate | Hold:
        """The uncompensated process forecast where the next correction shows, with the
        offsets applied: the whole of it is corrected, outside the forecast's own noise (and
        three times that for an offset that would reverse the last one)."""
        got = self.predictor.observe(deviation_mm, applied_mm, now_s, uncertainty_mm, time_s)
        if isinstance(got, tuple):
            return Hold(*got)
        where = got + applied_mm
        step = self.predictor.last_step_mm
        note = "" if step is None else (f"a step of {step * 1000:+.1f} um in the process, "
                                        "confirmed by two measurements: followed; ")
        null = self.predictor.null_band()
        if last_offset_mm * where > 0:  # it would reverse the last offset: surer
            null *= REVERSAL_NULL_BANDS
        return Estimate(where, 1.0, null, note)

    def applied(self, effect_mm: float, now_s: float) -> None:
        """An offset applied now, shown a dead time later."""
        self.predictor.applied(effect_mm, self.dead_measurements, now_s + self.dead_s, now_s)

    def use_dead_time(self, measurements: int, seconds: float,
                      drift_mm: float | None = None) -> None:
        """Wait this dead time from now on, the offsets in flight included."""
        self.dead_measurements, self.dead_s = measurements, seconds
        self.predictor.use_dead_time(measurements, seconds, drift_mm)

    def clear(self) -> None:
        """The estimate outlives the controller's states."""

    def restart(self, now_s: float) -> None:
        """The level starts again from the first part cut after now."""
        self.predictor.reset(self.dead_measurements, now_s + self.dead_s)


def law_of(settings: Any) -> Law:
    """The law the settings name (``law``), fresh."""
    return PredictiveLaw.of(settings) if settings.law == "predictive" else WindowLaw.of(settings)

