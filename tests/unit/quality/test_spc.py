"""Control limits, capability and run rules against the literature's tables and examples,
seeded simulation for the confidence intervals, and each run rule on its own pattern."""

from __future__ import annotations

import numpy as np
import pytest

from service.quality.spc import (
    c4,
    capability,
    cpk_interval,
    limits_from_subgroups,
    run_rules,
    xbar_s_limits,
)


@pytest.mark.parametrize(("n", "c4_", "a3", "b3", "b4"), [
    (2, 0.7979, 2.659, 0.0, 3.267), (5, 0.9400, 1.427, 0.0, 2.089),
    (10, 0.9727, 0.975, 0.284, 1.716), (25, 0.9896, 0.606, 0.565, 1.435)])
def test_the_chart_constants_match_the_table(n, c4_, a3, b3, b4) -> None:
    # Montgomery, Introduction to Statistical Quality Control, Appendix Table VI
    # ("Factors for constructing variables control charts").
    assert c4(n) == pytest.approx(c4_, abs=5e-5)
    lim = xbar_s_limits(0.0, 1.0, n)
    assert (lim.ucl, -lim.lcl, lim.s_lcl, lim.s_ucl) == pytest.approx((a3, a3, b3, b4),
                                                                      abs=5e-4)


def test_the_piston_ring_example() -> None:
    # Montgomery, Introduction to SQC, the piston-ring inside diameters (25 subgroups of 5):
    # grand mean 74.001 mm, s-bar 0.0094 mm -> X-bar chart 73.988 .. 74.014, S chart 0 ..
    # 0.0196 (the x-bar and s chart example of chapter 6).
    lim = xbar_s_limits(74.001, 0.0094, 5)
    assert (round(lim.lcl, 3), round(lim.ucl, 3)) == (73.988, 74.014)
    assert (lim.s_lcl, round(lim.s_ucl, 4)) == (0.0, 0.0196)
    assert lim.sigma_within == pytest.approx(0.0094 / 0.94, rel=1e-3)


def test_the_cpk_interval_example() -> None:
    # Montgomery, Introduction to SQC, section on confidence intervals for Cpk (Bissell's
    # approximation): n = 20, Cpk-hat = 1.33 -> 0.88 <= Cpk <= 1.78.
    lo, hi = cpk_interval(1.33, 20)
    assert (round(lo, 2), round(hi, 2)) == (0.88, 1.78)


def test_limits_from_subgroups_recover_the_process() -> None:
    rng = np.random.default_rng(7)
    x = rng.normal(30.0, 0.002, size=(200, 5))
    lim = limits_from_subgroups(x)
    assert lim.center == pytest.approx(30.0, abs=3e-4)
    assert lim.sigma_within == pytest.approx(0.002, rel=0.05)
    assert limits_from_subgroups(x[:1]) is None and limits_from_subgroups(x[:, :1]) is None


def test_capability_against_the_definitions() -> None:
    rng = np.random.default_rng(3)
    x = rng.normal(30.005, 0.004, 500)
    c = capability(x, 29.98, 30.02)
    s = x.std(ddof=1)
    assert c.pp == pytest.approx(0.04 / (6 * s))
    assert c.ppk == pytest.approx((30.02 - x.mean()) / (3 * s))
    assert c.cp == c.pp  # no within sigma given
    w = capability(x, 29.98, 30.02, sigma_within=0.002)
    assert w.cp == pytest.approx(0.04 / 0.012) and w.pp == c.pp
    one_sided = capability(x, None, 30.02)
    assert one_sided.cp is None and one_sided.cpk == pytest.approx(c.ppk)
    assert capability([1.0], 0, 2) is None
    assert capability([1.0, 1.0, 1.0], 0, 2).cp is None  # no spread: no index


@pytest.mark.parametrize("n", [25, 100])
def test_the_intervals_cover_the_true_index_about_95_percent(n: int) -> None:
    rng = np.random.default_rng(n)
    true_cp, true_cpk = 0.04 / 0.024, 0.015 / 0.012
    hits_cp = hits_cpk = 0
    runs = 2000
    for _ in range(runs):
        c = capability(rng.normal(30.005, 0.004, n), 29.98, 30.02)
        hits_cp += c.cp_ci[0] <= true_cp <= c.cp_ci[1]
        hits_cpk += c.cpk_ci[0] <= true_cpk <= c.cpk_ci[1]
    assert 0.93 <= hits_cp / runs <= 0.97
    assert 0.92 <= hits_cpk / runs <= 0.975  # Bissell's is an approximation


def fired(zones: list[float], rule: int) -> list[int]:
    return [v.index for v in run_rules(zones, [rule])]


def test_each_run_rule_on_its_pattern_and_not_on_noise() -> None:
    assert fired([0, 3.1, 0, -3.2], 1) == [1, 3]
    assert fired([0.5] * 8 + [0.1], 2) == [8]
    assert fired([0.5] * 8 + [-0.1], 2) == []
    assert fired([0, 0.1, 0.2, 0.3, 0.4, 0.5], 3) == [5]
    assert fired([0, 0.1, 0.2, 0.3, 0.4, 0.4], 3) == []
    assert fired([0.5 * (-1) ** i for i in range(14)], 4) == [13]
    assert fired([0, 2.1, 0.5, 2.2], 5) == [3]
    assert fired([0, 2.1, -2.5, 0], 5) == []
    assert fired([1.5, 1.2, 0.3, 1.1, 1.4], 6) == [4]
    assert fired([0.2] * 15, 7) == [14]
    assert fired([1.5, -1.5] * 4, 8) == [7]
    rng = np.random.default_rng(11)
    noise = list(np.clip(rng.normal(0, 1, 40), -2.9, 2.9))
    for rule in (1, 2, 3, 4):
        assert len(fired(noise, rule)) <= 1
