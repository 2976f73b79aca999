"""One measurement a segment: the frames of one feature in a row (the laser resting on a
part's segment while it turns) fused into the one value its tool's law takes
(``CompensationSettings.judge = "segment"``).

The frames of a segment share that part's scatter. Judged one by one, thirty frames of one
part read as thirty parts: the law takes the part's scatter for the process and chases it,
and counts its dead time in frames that come in bursts, a segment at a time. Fused, each
part gives each feature one value, and the dead time is counted in segments.

A segment ends when a frame of another feature comes, or when nothing came for ``gap_s``
(the part left the gauge). Its value is the frames' mean weighted by 1 / uncertainty^2, its
uncertainty that of the mean; its sequence number and time the last frame's.

Pure: measurements in, measurements out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Generic, TypeVar

from service.compensation.records import MeasurementIn

K = TypeVar("K")


@dataclass
class SegmentFusion(Generic[K]):
    """Fuses each segment's good frames (see the module's docstring). ``K`` is what names a
    segment's feature (the job's feature, handed back with the fused value)."""

    gap_s: float = 10.0
    _of: tuple[K, int] | None = None      # the feature under way and its number
    _sums: tuple[float, float, float] = (0.0, 0.0, 0.0)  # weights, weighted (d - first), first
    _last: MeasurementIn | None = None

    def add(self, m: MeasurementIn, feature: K, number: int
            ) -> tuple[MeasurementIn, K] | None:
        """A good frame ``m`` (a diameter and an uncertainty) of ``feature``, numbered
        ``number``; the segment it ended, fused, with its feature, if it ended one."""
        if m.diameter_mm is None or m.uncertainty_mm is None:
            raise ValueError("only a frame with a diameter and an uncertainty is fused")
        done = None
        if self._last is not None and self._of is not None and (
                number != self._of[1] or m.time_s - self._last.time_s > self.gap_s):
            done = self.flush()
        w = 1.0 / max(float(m.uncertainty_mm), 1e-6) ** 2
        sum_w, sum_wd, first = self._sums if self._last is not None else \
            (0.0, 0.0, float(m.diameter_mm))
        self._sums = (sum_w + w, sum_wd + w * (float(m.diameter_mm) - first), first)
        self._of, self._last = (feature, number), m
        return done

    def flush(self) -> tuple[MeasurementIn, K] | None:
        """End the segment under way now (the job changed); it fused, or None."""
        if self._last is None or self._of is None:
            return None
        sum_w, sum_wd, first = self._sums
        fused = replace(self._last, diameter_mm=first + sum_wd / sum_w,
                        uncertainty_mm=1.0 / math.sqrt(sum_w))
        out = (fused, self._of[0])
        self._of, self._last, self._sums = None, None, (0.0, 0.0, 0.0)
        return out
