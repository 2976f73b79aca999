"""The live SPC of the gauge's feature: a feed listener that feeds the pure ``SpcMonitor``
with each good fused diameter, follows the feature, and tells live subscribers when a run rule
fires."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from service.config import SpcConfig
from service.quality.monitor import SpcMonitor, SpcSettings, Subgroup
from service.record import Feature, MeasurementRecord
from service.runtime.feed import Subscribers


class SpcService:
    """Owns the ``SpcMonitor``; changed on the event loop only.

    Parameters
    ----------
    config : SpcConfig
        Subgroups, baseline, window and rules.
    fuse_frames : int
        The spacing of a subgroup's values when the config leaves it open.
    feature : callable
        The feature in force (nominal and tolerance, mm).
    """

    def __init__(self, config: SpcConfig, fuse_frames: int,
                 feature: Callable[[], Feature]) -> None:
        self.monitor = SpcMonitor(SpcSettings(
            subgroup_size=config.subgroup_size,
            member_spacing=config.member_spacing or fuse_frames, every_s=config.every_s,
            baseline_subgroups=config.baseline_subgroups,
            window_subgroups=config.window_subgroups, rules=tuple(config.rules)))
        self.feature = feature
        self.events = Subscribers()
        self._feature_seen: Feature | None = None

    def _follow_feature(self) -> None:
        f = self.feature()
        if f == self._feature_seen:
            return
        self._feature_seen = f
        n = f.nominal_mm
        self.monitor.set_feature(n, None if n is None else n + f.tol_lower_mm,
                                 None if n is None else n + f.tol_upper_mm)

    def __call__(self, record: MeasurementRecord) -> None:
        """A published record (a feed listener)."""
        self._follow_feature()
        if record.status != "ok":
            return
        sg = self.monitor.add(record.fused_diameter_mm, record.time)
        if sg is not None and sg.rules:
            self.events.publish(event(sg))

    def reset(self) -> None:
        """A new baseline from now."""
        self.monitor.reset()

    @property
    def rule_violation(self) -> bool:
        """A rule fired at the latest subgroup."""
        return self.monitor.violation is not None

    def figures(self) -> dict[str, Any]:
        """``GET /api/v1/spc``."""
        self._follow_feature()
        return self.monitor.figures()


def event(sg: Subgroup) -> dict[str, Any]:
    """The live stream's ``spc`` event for a subgroup at which rules fired."""
    return {"subgroup": sg.index, "time": sg.time, "mean_mm": sg.mean,
            "rules": sg.as_dict()["rules"]}
