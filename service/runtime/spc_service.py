"""The live SPC of each feature: a feed listener that feeds a pure ``SpcMonitor`` a feature
with each good fused diameter of it, follows the features' nominals and tolerances, and
tells live subscribers when a run rule fires."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from service.config import SpcConfig
from service.measurement_record import Feature, MeasurementRecord
from service.quality.monitor import SpcMonitor, SpcSettings, Subgroup
from service.runtime.feed import Subscribers


class SpcService:
    """Owns a ``SpcMonitor`` a feature; changed on the event loop only.

    Parameters
    ----------
    config : SpcConfig
        Subgroups, baseline, window and rules.
    fuse_frames : int
        The spacing of a subgroup's values when the config leaves it open.
    feature : callable
        What a record was compared with (``feature(record)``: its feature's nominal and
        tolerance, mm).
    """

    def __init__(self, config: SpcConfig, fuse_frames: int,
                 feature: Callable[[MeasurementRecord], Feature]) -> None:
        self.settings = SpcSettings(
            subgroup_size=config.subgroup_size,
            member_spacing=config.member_spacing or fuse_frames, every_s=config.every_s,
            baseline_subgroups=config.baseline_subgroups,
            window_subgroups=config.window_subgroups, rules=tuple(config.rules))
        self.feature = feature
        self.events = Subscribers()
        self.monitors: dict[int, SpcMonitor] = {}
        self._seen: dict[int, Feature] = {}
        self.latest_feature: int | None = None

    def _monitor(self, number: int, f: Feature) -> SpcMonitor:
        monitor = self.monitors.get(number)
        if monitor is None:
            monitor = self.monitors[number] = SpcMonitor(self.settings)
        if self._seen.get(number) != f:  # a new nominal starts a new baseline
            self._seen[number] = f
            n = f.nominal_mm
            monitor.set_feature(n, None if n is None else n + f.tol_lower_mm,
                                None if n is None else n + f.tol_upper_mm)
        return monitor

    def __call__(self, record: MeasurementRecord) -> None:
        """A published record (a feed listener)."""
        if record.feature is None:
            return
        monitor = self._monitor(record.feature, self.feature(record))
        self.latest_feature = record.feature
        if record.status != "ok":
            return
        sg = monitor.add(record.fused_diameter_mm, record.time)
        if sg is not None and sg.rules:
            self.events.publish({**event(sg), "feature": record.feature})

    def reset(self) -> None:
        """A new baseline from now, for every feature."""
        for monitor in self.monitors.values():
            monitor.reset()

    def forget(self) -> None:
        """Another job: its features are others."""
        self.monitors.clear()
        self._seen.clear()
        self.latest_feature = None

    @property
    def rule_violation(self) -> bool:
        """A rule fired at a feature's latest subgroup."""
        return any(m.violation is not None for m in self.monitors.values())

    def figures(self, feature: int | None = None) -> dict[str, Any]:
        """``GET /api/v1/spc``: a feature's figures (by default the one measured last;
        KeyError for a feature with none yet), and the features that have some."""
        number = self.latest_feature if feature is None else feature
        if number is None or number not in self.monitors:
            if feature is not None:
                raise KeyError(f"no SPC of feature {feature} yet (features with SPC: "
                               f"{sorted(self.monitors) or 'none'})")
            return {**SpcMonitor(self.settings).figures(), "feature": None, "features": []}
        return {**self.monitors[number].figures(), "feature": number,
                "features": sorted(self.monitors)}


def event(sg: Subgroup) -> dict[str, Any]:
    """The live stream's ``spc`` event for a subgroup at which rules fired."""
    return {"subgroup": sg.index, "time": sg.time, "mean_mm": sg.mean,
            "rules": sg.as_dict()["rules"]}
