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
share, however fast the tool wears. Only differences taken close together count (within
three times the shortest usual gap): coming back to the first feature of the next part
crosses a part's wear.

Within the bound, the features' constant differences are learnt from the same pairwise
differences, and the tool is aimed where they leave every feature the most margin to its
tolerance (``aim``): a tighter feature is put nearer its nominal than a wider one, where a
plain mean would give each half the difference.

Pure; lengths in mm of diameter.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

PAIRS_KEPT = 32
"""A pair's constant difference is learnt from its last this many differences ..."""
PAIRS_JUDGED = 8
"""... and the pair is judged on its last this many (a new disagreement shows sooner)."""
PAIRS_NEEDED = 3
"""... once it has this many."""
DISAGREEMENT_SIGMAS = 2.0
"""Scatter allowed beside the bound: a difference within it of zero is agreement."""


@dataclass
class FeatureAgreement:
    """Differences between consecutive measurements of a tool's features, pair by pair."""

    kept: int = PAIRS_KEPT
    _last: tuple[int, float, float, float] | None = None
    _pairs: dict[tuple[int, int], deque[tuple[float, float, float]]] = field(
        default_factory=dict)

    def add(self, feature: int, deviation_mm: float, uncertainty_mm: float,
            time_s: float) -> None:
        """A measurement of ``feature`` taken at ``time_s``: its deviation less its
        empirical value."""
        if self._last is not None and self._last[0] != feature:
            a, dev_a, u_a, t_a = self._last
            key, diff = ((a, feature), deviation_mm - dev_a) if a < feature else \
                ((feature, a), dev_a - deviation_mm)
            self._pairs.setdefault(key, deque(maxlen=self.kept)).append(
                (diff, math.hypot(uncertainty_mm, u_a), abs(time_s - t_a)))
        self._last = (feature, deviation_mm, uncertainty_mm, time_s)

    def _close(self) -> dict[tuple[int, int], list[tuple[float, float]]]:
        """Each pair's differences taken close together (see the module's docstring)."""
        gaps = sorted(g for q in self._pairs.values() for _, _, g in q)
        if not gaps:
            return {}
        within = 3.0 * max(gaps[len(gaps) // 4], 1e-9)
        return {key: [(d, u) for d, u, g in q if g <= within]
                for key, q in self._pairs.items()}

    def applied(self) -> None:
        """An offset reaches the parts now: no difference across it."""
        self._last = None

    def relative_levels(self) -> dict[int, float]:
        """Each feature's constant difference from the tool's first feature (the smallest
        number with enough differences), from the pairs' medians, along the pairs that link
        them (the features measured one after the other)."""
        step: dict[int, list[tuple[int, float]]] = {}
        for (a, b), q in self._close().items():
            if len(q) >= PAIRS_NEEDED:
                median = _median([d for d, _ in q])
                step.setdefault(a, []).append((b, median))
                step.setdefault(b, []).append((a, -median))
        if not step:
            return {}
        ref = min(step)
        out, todo = {ref: 0.0}, [ref]
        while todo:
            here = todo.pop()
            for there, diff in step[here]:
                if there not in out:
                    out[there] = out[here] + diff
                    todo.append(there)
        return out

    def disagreement(self, bound_mm: float) -> str:
        """Why the features disagree beyond ``bound_mm`` and their scatter ("" when they
        do not, or not yet enough is known)."""
        worst, said = 0.0, ""
        for (a, b), q in sorted(self._close().items()):
            if len(q) < PAIRS_NEEDED:
                continue
            recent = q[-PAIRS_JUDGED:]
            diffs = [d for d, _ in recent]
            n = len(diffs)
            median = _median(diffs)
            mad = sorted(abs(d - median) for d in diffs)[n // 2]
            own = math.sqrt(sum(u * u for _, u in recent) / n)
            sigma = max(1.4826 * mad, own) * math.sqrt(math.pi / 2 / n)
            excess = abs(median) - DISAGREEMENT_SIGMAS * sigma
            if excess > bound_mm and excess > worst:
                worst = excess
                said = (f"features {a} and {b} disagree by {median * 1000:+.1f} um (beyond "
                        f"{bound_mm * 1000:.1f} um and their scatter): a taper or a "
                        "deflection; the tool is held until they agree, or an empirical "
                        "value takes the difference")
        return said


def _median(values: list[float]) -> float:
    v = sorted(values)
    return 0.5 * (v[(len(v) - 1) // 2] + v[len(v) // 2])


def aim(levels: dict[int, float], tolerances: dict[int, tuple[float, float]]) -> float:
    """Where to put the tool's common level ``c`` (each feature then stands at its level
    less ``c``) so that the smallest margin of any feature to its tolerance
    (``(lower, upper)``, deviations) is the largest: among each feature's centre and the
    points where two features' margins are equal, the best."""
    if not levels:
        return 0.0

    def worst(c: float) -> float:
        return min(min(up - (d - c), (d - c) - lo) for d, (lo, up) in
                   ((levels[f], tolerances[f]) for f in levels))

    candidates = [d - 0.5 * (tolerances[f][0] + tolerances[f][1]) for f, d in levels.items()]
    for i, j in ((i, j) for i in levels for j in levels if i != j):
        # i's upper margin equal to j's lower margin
        candidates.append(0.5 * (levels[i] + levels[j] - tolerances[i][1] - tolerances[j][0]))
    return max(candidates, key=lambda c: (round(worst(c), 12), -abs(c)))
