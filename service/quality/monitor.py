"""SPC of the live process: subgroups of fused diameters, limits from a baseline, capability
over a window, run-rule events. A pure state machine: values and times are passed in.

A subgroup is ``subgroup_size`` fused values taken ``member_spacing`` measurements apart (so
that no two share a frame: a fused value is the mean of the last ``fuse_frames`` frames, and
neighbours would be nearly the same number), one subgroup started every ``every_s`` seconds.
The first ``baseline_subgroups`` subgroups after a start, a reset or a new nominal set the
control limits (X-bar/S, 3 sigma); every later subgroup is judged against them by Nelson's
rules. Capability (Cp, Cpk from the within-subgroup sigma; Pp, Ppk from all values) over the
last ``window_subgroups`` subgroups against the feature's limits.
"""

from __future__ import annotations

import collections
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from service.quality.spc import (
    RULES,
    XbarSLimits,
    capability,
    limits_from_subgroups,
    rules_at_end,
)


@dataclass(frozen=True)
class SpcSettings:
    """How subgroups are formed and judged."""

    subgroup_size: int = 5
    member_spacing: int = 10
    every_s: float = 5.0
    baseline_subgroups: int = 20
    window_subgroups: int = 125
    rules: tuple[int, ...] = tuple(RULES)


@dataclass(frozen=True)
class Subgroup:
    """One closed subgroup: its values (mm), mean, standard deviation, time (Unix s, of its
    last value) and the rules that fired at it (empty in the baseline)."""

    index: int
    time: float
    values: tuple[float, ...]
    mean: float
    std: float
    baseline: bool
    rules: tuple[int, ...] = ()

    def as_dict(self) -> dict[str, Any]:
        return {"index": self.index, "time": self.time, "mean_mm": self.mean,
                "std_mm": self.std, "values_mm": list(self.values), "baseline": self.baseline,
                "rules": [{"rule": r, "text": RULES[r]} for r in self.rules]}


@dataclass
class SpcMonitor:
    """The SPC state of one characteristic."""

    settings: SpcSettings = field(default_factory=SpcSettings)
    nominal: float | None = None
    lsl: float | None = None
    usl: float | None = None
    limits: XbarSLimits | None = None
    subgroups: collections.deque[Subgroup] = field(default_factory=collections.deque)
    _members: list[float] = field(default_factory=list)
    _since_member: int = 0
    _next_start_s: float = -math.inf
    _count: int = 0

    def set_feature(self, nominal: float | None, lsl: float | None, usl: float | None) -> bool:
        """The feature's nominal and absolute limits (mm); a new nominal starts a new
        baseline. True when it did."""
        new = nominal != self.nominal
        self.nominal, self.lsl, self.usl = nominal, lsl, usl
        if new:
            self.reset()
        return new

    def reset(self) -> None:
        """Forget the subgroups and limits: a new baseline begins."""
        self.limits = None
        self.subgroups.clear()
        self._members = []
        self._since_member = 0
        self._next_start_s = -math.inf

    def add(self, fused_mm: float | None, time_s: float) -> Subgroup | None:
        """One measurement's fused value (None or NaN: not counted); the subgroup it closed,
        if it closed one."""
        if fused_mm is None or not math.isfinite(fused_mm) or self.nominal is None:
            return None
        if not self._members:
            if time_s < self._next_start_s:
                return None
            self._next_start_s = time_s + self.settings.every_s
            self._members.append(fused_mm)
            self._since_member = 0
            return None
        self._since_member += 1
        if self._since_member < self.settings.member_spacing:
            return None
        self._members.append(fused_mm)
        self._since_member = 0
        if len(self._members) < self.settings.subgroup_size:
            return None
        return self._close(time_s)

    def _close(self, time_s: float) -> Subgroup:
        values = tuple(self._members)
        self._members = []
        x = np.asarray(values)
        mean, std = float(x.mean()), float(x.std(ddof=1))
        self._count += 1
        if self.limits is None:
            sg = Subgroup(self._count, time_s, values, mean, std, baseline=True)
            self._keep(sg)
            base = [s for s in self.subgroups if s.baseline]
            if len(base) >= self.settings.baseline_subgroups:
                self.limits = limits_from_subgroups(np.array([s.values for s in base]))
            return sg
        judged = [s for s in self.subgroups if not s.baseline]
        zones = [self.limits.zone(s.mean) for s in judged] + [self.limits.zone(mean)]
        fired = rules_at_end(zones, self.settings.rules)
        sg = Subgroup(self._count, time_s, values, mean, std, baseline=False, rules=fired)
        self._keep(sg)
        return sg

    def _keep(self, sg: Subgroup) -> None:
        self.subgroups.append(sg)
        keep = max(self.settings.window_subgroups, self.settings.baseline_subgroups)
        while len(self.subgroups) > keep:  # the baseline's subgroups stay while the limits do
            self.subgroups.popleft()

    @property
    def violation(self) -> Subgroup | None:
        """The latest subgroup when a rule fired at it (the live process is out of control
        now), else None."""
        return self.subgroups[-1] if self.subgroups and self.subgroups[-1].rules else None

    def figures(self) -> dict[str, Any]:
        """The current figures, JSON-ready (lengths in mm)."""
        window = list(self.subgroups)[-self.settings.window_subgroups:]
        values = [v for s in window for v in s.values]
        within = None
        if len(window) >= 2:
            lim = limits_from_subgroups(np.array([s.values for s in window]))
            within = lim.sigma_within if lim else None
        cap = capability(values, self.lsl, self.usl, within) if values else None
        lim = self.limits
        base = sum(1 for s in self.subgroups if s.baseline)
        return {
            "n": len(values), "subgroups": len(window),
            "subgroup_size": self.settings.subgroup_size,
            "baseline": {"subgroups": base, "needed": self.settings.baseline_subgroups,
                         "complete": lim is not None},
            "nominal_mm": self.nominal, "lsl_mm": self.lsl, "usl_mm": self.usl,
            "mean_mm": None if cap is None else cap.mean,
            "std_mm": None if cap is None else cap.std_overall,
            "sigma_within_mm": within,
            **{k: None if cap is None else getattr(cap, k)
               for k in ("cp", "cpk", "pp", "ppk")},
            "cp_ci": None if cap is None or cap.cp_ci is None else list(cap.cp_ci),
            "cpk_ci": None if cap is None or cap.cpk_ci is None else list(cap.cpk_ci),
            "limits": None if lim is None else {
                "center_mm": lim.center, "ucl_mm": lim.ucl, "lcl_mm": lim.lcl,
                "s_center_mm": lim.s_center, "s_ucl_mm": lim.s_ucl, "s_lcl_mm": lim.s_lcl},
            "violations": [sg.as_dict() for sg in self.subgroups if sg.rules][-20:],
            "rule_violation": self.violation is not None,
            "points": [sg.as_dict() for sg in window],
        }
