"""One tool, several features: how their deviations make one correction, and when they
disagree too much for one.

Each feature's deviation is taken less its empirical value (``JobFeature.empirical_mm``):
what is left is the tool's wear as that feature shows it, and it goes into the tool's law
measurement by measurement (``tools``). The law's mean value is then a mean over parts and
features alike, each measurement counted once.

The features of one tool should agree within their scatter. When they do not (a taper, a
slender segment that deflects), one correction would split the difference and move both
off nominal: the tool is held, and the reason names the pair and the difference, so that a
person sets an empirical value or looks at the machine. Agreement is judged from the
differences between consecutive measurements of two features of the tool: the tool's wear
and its offsets move both alike, so a difference shows only what the features do not
share, however fast the tool wears.

Pure; lengths in mm of diameter.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

PAIRS_KEPT = 8
"""A pair of features is judged on its last this many differences."""
PAIRS_NEEDED = 3
"""... once it has this many."""
DISAGREEMENT_SIGMAS = 2.0
"""Scatter allowed beside the bound: a difference within it of zero is agreement."""


@dataclass
class FeatureAgreement:
    """Differences between consecutive measurements of a tool's features, pair by pair."""

    kept: int = PAIRS_KEPT
    _last: tuple[int, float, float] | None = None
    _pairs: dict[tuple[int, int], deque[tuple[float, float]]] = field(default_factory=dict)

    def add(self, feature: int, deviation_mm: float, uncertainty_mm: float) -> None:
        """A measurement of ``feature``: its deviation less its empirical value."""
        if self._last is not None and self._last[0] != feature:
            a, dev_a, u_a = self._last
            key, diff = ((a, feature), deviation_mm - dev_a) if a < feature else \
                ((feature, a), dev_a - deviation_mm)
            self._pairs.setdefault(key, deque(maxlen=self.kept)).append(
                (diff, math.hypot(uncertainty_mm, u_a)))
        self._last = (feature, deviation_mm, uncertainty_mm)

    def applied(self) -> None:
        """An offset reaches the parts now: no difference across it."""
        self._last = None

    def disagreement(self, bound_mm: float) -> str:
        """Why the features disagree beyond ``bound_mm`` and their scatter ("" when they
        do not, or not yet enough is known)."""
        worst, said = 0.0, ""
        for (a, b), q in sorted(self._pairs.items()):
            if len(q) < PAIRS_NEEDED:
                continue
            diffs = sorted(d for d, _ in q)
            n = len(diffs)
            median = 0.5 * (diffs[(n - 1) // 2] + diffs[n // 2])
            mad = sorted(abs(d - median) for d in diffs)[n // 2]
            own = math.sqrt(sum(u * u for _, u in q) / n)
            sigma = max(1.4826 * mad, own) * math.sqrt(math.pi / 2 / n)
            excess = abs(median) - DISAGREEMENT_SIGMAS * sigma
            if excess > bound_mm and excess > worst:
                worst = excess
                said = (f"features {a} and {b} disagree by {median * 1000:+.1f} um (beyond "
                        f"{bound_mm * 1000:.1f} um and their scatter): a taper or a "
                        "deflection; the tool is held until they agree, or an empirical "
                        "value takes the difference")
        return said
