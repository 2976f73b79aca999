"""The controller's two laws: the measuring cycle's window (``WindowLaw``) and the predictive
run-to-run law (``Predictor``): the process as the gauge sees it without compensation,
filtered by a double exponentially weighted moving average, corrected with the offsets that
are applied but not visible yet.

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

Pure: deviations and effects in mm of diameter, time passed in.
"""

from __future__ import annotations

import collections
import math
import statistics
from dataclasses import dataclass, field, replace
from typing import Any


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

    @classmethod
    def of(cls, settings: Any) -> WindowLaw:
        """For compensation settings (``window``, ``filter``, the dead times); no dead time
        at the start."""
        return cls(settings.window, settings.filter, settings.dead_time_measurements,
                   settings.dead_time_s, collections.deque(maxlen=settings.window),
                   settings.dead_time_measurements)

    def retuned(self, settings: Any) -> WindowLaw:
        """An empty window for new settings, the dead time running on."""
        return replace(WindowLaw.of(settings), since_correction=self.since_correction,
                       correction_time=self.correction_time)

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


@dataclass
class Predictor:
    """Level and trend of the uncompensated process, and the offsets in flight.

    Attributes
    ----------
    gain : float
        ``lam``, the share of each measurement taken into the level (feedback).
    trend_gain : float
        ``beta``, the share of each level change taken into the trend (0: a single EWMA).
    horizon : int
        How many measurements ahead the forecast looks (dead time in measurements + 1).
    """

    gain: float
    trend_gain: float
    horizon: int
    level: float | None = None
    trend: float = 0.0
    in_flight: list[InFlight] = field(default_factory=list)

    @classmethod
    def of(cls, settings: Any) -> Predictor:
        """A fresh predictor for compensation settings (``gain``, ``trend_gain``,
        ``dead_time_measurements``)."""
        return cls(settings.gain, settings.trend_gain, settings.dead_time_measurements + 1)

    def retuned(self, settings: Any) -> Predictor:
        """This predictor's estimate and offsets in flight with new settings' gains."""
        return replace(Predictor.of(settings), level=self.level, trend=self.trend,
                       in_flight=self.in_flight)

    def applied(self, effect_mm: float, after_measurements: int, visible_at_s: float) -> None:
        """An offset was applied: its effect on the diameter (mm) shows from the measurement
        after ``after_measurements`` more, at ``visible_at_s`` at the earliest."""
        self.in_flight.append(InFlight(effect_mm, after_measurements, visible_at_s))

    def in_flight_mm(self) -> float:
        """The effect of the offsets not yet visible, mm of diameter."""
        return sum(f.effect_mm for f in self.in_flight)

    def observe(self, deviation_mm: float, applied_mm: float, now_s: float) -> float:
        """Take a measurement's deviation from nominal, with ``applied_mm`` the effect of all
        offsets applied so far; return the forecast of the uncompensated process ``horizon``
        measurements ahead (mm)."""
        for f in self.in_flight:
            f.seen += 1
        self.in_flight = [f for f in self.in_flight
                          if not (f.seen > f.after_measurements and now_s >= f.visible_at_s)]
        u = deviation_mm - applied_mm + self.in_flight_mm()
        if self.level is None:
            self.level, self.trend = u, 0.0
        else:
            before = self.level
            self.level = self.gain * u + (1.0 - self.gain) * (self.level + self.trend)
            self.trend = self.trend_gain * (self.level - before) \
                + (1.0 - self.trend_gain) * self.trend
        return self.level + self.horizon * self.trend

    def reset(self) -> None:
        """A reset (a new insert): the next measurement starts the level afresh; the trend,
        the insert's wear per measurement, is kept (the same cut wears the next insert
        alike) and corrected from there."""
        self.level, self.in_flight = None, []
