"""How often the costlier checks of a frame are asked: pure state, time passed in.

Looking for a reflection beside the stripe (``service.measure.reflection``) costs about one
and a half frames' worth of CPU, so neither the service nor the offline ``measure`` asks it of
every frame: a few times a second, and of every frame while the last check found one (a
reflection from a machine part stays while that part is lit). A lopsided stripe is always
checked by the measurement itself.
"""

from __future__ import annotations

import math

__all__ = ["ReflectionWatch"]


class ReflectionWatch:
    """When the next frame should be checked for a reflection.

    Parameters
    ----------
    hz : float
        Checks a second while no reflection is seen; 0 checks no frame but the lopsided ones
        (which the measurement always checks); ``inf`` checks every frame.
    """

    def __init__(self, hz: float) -> None:
        self.hz = float(hz)
        self._last_s: float | None = None
        self.present = False

    def due(self, now_s: float) -> bool:
        """Whether the frame taken at ``now_s`` is checked (and, if so, counted as the check)."""
        if self.hz <= 0:
            return self.present
        if math.isinf(self.hz):
            return True
        # A hair's tolerance: frames at exactly the rate are not pushed to the next one.
        if (self.present or self._last_s is None
                or (now_s - self._last_s) * self.hz >= 1.0 - 1e-6):
            self._last_s = now_s
            return True
        return False

    def seen(self, checked: bool, found: bool) -> None:
        """A frame's result: a reflection found keeps every frame checked until a checked
        frame finds none."""
        if found:
            self.present = True
        elif checked:
            self.present = False
