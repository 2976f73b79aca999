"""The live SPC state machine: subgroups spaced so that no two values share frames, a
baseline, then run rules on a shifted process; a new nominal starts again."""

from __future__ import annotations

import numpy as np
import pytest

from service.quality.monitor import SpcMonitor, SpcSettings


def feed(mon: SpcMonitor, values, t0: float = 0.0, dt: float = 0.1) -> list:
    closed = []
    for i, v in enumerate(values):
        sg = mon.add(v, t0 + i * dt)
        if sg is not None:
            closed.append(sg)
    return closed


def test_a_stable_process_sets_limits_and_a_shift_fires_the_rules() -> None:
    s = SpcSettings(subgroup_size=5, member_spacing=3, every_s=2.0, baseline_subgroups=10)
    mon = SpcMonitor(s)
    mon.set_feature(30.0, 29.98, 30.02)
    rng = np.random.default_rng(1)
    # one measurement every 0.1 s: a subgroup every 2 s (5 values 3 apart take 1.3 s)
    closed = feed(mon, 30.0 + rng.normal(0, 0.002, 200))
    assert len(closed) == 10 and all(sg.baseline for sg in closed)
    assert all(len(sg.values) == 5 for sg in closed)
    lim = mon.limits
    assert lim is not None and lim.center == pytest.approx(30.0, abs=0.002)
    assert lim.sigma_within == pytest.approx(0.002, rel=0.35)
    f = mon.figures()
    assert f["n"] == 50 and f["baseline"]["complete"] and f["cpk"] > 1.5
    assert not f["rule_violation"]

    stable = feed(mon, 30.0 + rng.normal(0, 0.002, 200), t0=20.0)
    assert sum(bool(sg.rules) for sg in stable) <= 1  # 10 judged subgroups of noise
    shifted = feed(mon, 30.008 + rng.normal(0, 0.002, 200), t0=40.0)
    assert any(1 in sg.rules for sg in shifted)  # 0.008 mm is ~9 sigma of a mean of 5
    assert mon.figures()["rule_violation"] and mon.figures()["violations"]


def test_values_without_a_nominal_or_a_fused_value_do_not_count() -> None:
    mon = SpcMonitor(SpcSettings(subgroup_size=2, member_spacing=1, every_s=0.0,
                                 baseline_subgroups=2))
    assert feed(mon, [30.0] * 10) == []  # no nominal yet
    mon.set_feature(30.0, None, None)
    assert feed(mon, [None, float("nan")] * 5) == []
    assert len(feed(mon, [30.0, 30.001] * 4)) == 4


def test_a_new_nominal_starts_a_new_baseline() -> None:
    mon = SpcMonitor(SpcSettings(subgroup_size=2, member_spacing=1, every_s=0.0,
                                 baseline_subgroups=2))
    mon.set_feature(30.0, 29.98, 30.02)
    feed(mon, [30.0, 30.001, 30.002, 29.999] * 3)
    assert mon.limits is not None
    assert mon.set_feature(30.0, 29.97, 30.03) is False and mon.limits is not None
    assert mon.set_feature(31.0, 30.98, 31.02) is True
    assert mon.limits is None and not mon.subgroups
