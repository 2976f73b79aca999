"""The camera's region of interest follows the stripe: a state machine with time passed in.

A sensor read in fewer rows delivers more frames per second and fewer bytes per frame. After
each measured frame ``RegionFollower.update`` says whether to change the region: narrow a
whole-sensor read to the stripe's box plus a margin; move or widen the region when the stripe
comes within half the margin of an edge that is not the sensor's; go back to the whole sensor
when no stripe has been found in a few frames (a new part, the laser off, a chip in the way).
The pipeline hands the answer to ``Camera.set_region``; the camera rounds it to its increments
and tags every frame with the region it was read with.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

Region = tuple[int, int, int, int]
"""x, y, width, height on the sensor, px."""


class _Keep:
    """No change to the region."""

    def __repr__(self) -> str:
        return "KEEP"


KEEP = _Keep()


@dataclass
class RegionFollower:
    """Decides the region of interest from each frame's stripe.

    Parameters
    ----------
    sensor : (int, int)
        Sensor width and height, px (the calibration's image size).
    margin_px : int
        Pixels kept around the stripe's box.
    lost_after : int
        Frames in a row without a stripe before the whole sensor is read again.
    min_interval_s : float
        Least time between two changes that follow the stripe (going back to the whole
        sensor is not held back).
    settle_s : float
        How long a frame may still come from the region before the last one asked for.
    narrow_below : float
        A whole-sensor read is narrowed when the stripe's region is smaller than this share
        of the sensor.
    """

    sensor: tuple[int, int]
    margin_px: int = 32
    lost_after: int = 3
    min_interval_s: float = 0.25
    settle_s: float = 1.0
    narrow_below: float = 0.8
    requested: Region | None = None
    _misses: int = 0
    _changed_s: float = -1e9

    def update(self, points_px: np.ndarray | None, frame_region: Region | None, now_s: float
               ) -> Region | _Keep | None:
        """The region to ask for after a frame, or ``KEEP``.

        Parameters
        ----------
        points_px : ndarray, shape (N, 2), or None
            The frame's stripe centres in sensor pixels; None when it had no stripe.
        frame_region : Region or None
            The region the frame was read with (None: the whole sensor).
        now_s : float
            Monotonic time, s.
        """
        waiting = not _close(frame_region, self.requested) \
            and now_s - self._changed_s < self.settle_s
        if points_px is None or len(points_px) == 0:
            self._misses += 1
            if self._misses >= self.lost_after and self.requested is not None:
                return self._ask(None, now_s)
            return KEEP
        self._misses = 0
        if waiting or now_s - self._changed_s < self.min_interval_s:
            return KEEP
        target = self.around(points_px)
        if frame_region is None:
            sw, sh = self.sensor
            if target[2] * target[3] < self.narrow_below * sw * sh:
                return self._ask(target, now_s)
            return KEEP
        if self._near_an_edge(points_px, frame_region):
            return self._ask(target, now_s)
        return KEEP

    def around(self, points_px: np.ndarray) -> Region:
        """The stripe's box plus the margin, within the sensor."""
        sw, sh = self.sensor
        lo = np.floor(points_px.min(axis=0)).astype(int) - self.margin_px
        hi = np.ceil(points_px.max(axis=0)).astype(int) + self.margin_px + 1
        x0, y0 = max(0, int(lo[0])), max(0, int(lo[1]))
        x1, y1 = min(sw, int(hi[0])), min(sh, int(hi[1]))
        return x0, y0, x1 - x0, y1 - y0

    def _near_an_edge(self, points_px: np.ndarray, region: Region) -> bool:
        """Whether the stripe comes within half the margin of an edge of the region that is
        not the sensor's own."""
        sw, sh = self.sensor
        x, y, w, h = region
        guard = self.margin_px / 2.0
        lo, hi = points_px.min(axis=0), points_px.max(axis=0)
        return bool((x > 0 and lo[0] < x + guard) or (y > 0 and lo[1] < y + guard)
                    or (x + w < sw and hi[0] > x + w - guard)
                    or (y + h < sh and hi[1] > y + h - guard))

    def _ask(self, region: Region | None, now_s: float) -> Region | None:
        self.requested, self._changed_s = region, now_s
        return region


def _close(a: Region | None, b: Region | None, tolerance_px: int = 16) -> bool:
    """Whether a region read matches one asked for, up to the camera's rounding."""
    if a is None or b is None:
        return a is b
    return max(abs(p - q) for p, q in zip(a, b, strict=True)) <= tolerance_px
