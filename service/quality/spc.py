"""Statistical process control of one characteristic: X-bar/S control limits, capability
indices with confidence intervals, and the Western Electric / Nelson run rules.

References: D. C. Montgomery, *Introduction to Statistical Quality Control* (X-bar and S
charts, the constants c4, A3, B3, B4; confidence intervals of Cp and Cpk); L. S. Nelson, "The
Shewhart Control Chart - Tests for Special Causes", J. Quality Technology 16(4), 1984 (rules
1-8). Lengths in the caller's unit (mm in the service).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy import special  # not scipy.stats: its import costs the service's start 0.5 s
from scipy.special import gammaln


def c4(n: int) -> float:
    """The bias constant of the sample standard deviation: E[s] = c4(n) sigma (n >= 2)."""
    if n < 2:
        raise ValueError("c4 needs n >= 2")
    return math.sqrt(2.0 / (n - 1)) * math.exp(gammaln(n / 2.0) - gammaln((n - 1) / 2.0))


@dataclass(frozen=True)
class XbarSLimits:
    """Control limits of an X-bar and an S chart for subgroups of ``n``.

    ``sigma_within`` = s-bar / c4(n): the process's short-term standard deviation.
    """

    n: int
    center: float
    ucl: float
    lcl: float
    s_center: float
    s_ucl: float
    s_lcl: float
    sigma_within: float

    def zone(self, xbar: float) -> float:
        """How many sigmas of the mean (sigma_within / sqrt(n)) ``xbar`` lies from the
        center line (signed)."""
        sigma_xbar = self.sigma_within / math.sqrt(self.n)
        return (xbar - self.center) / sigma_xbar if sigma_xbar > 0 else 0.0


def xbar_s_limits(center: float, s_bar: float, n: int) -> XbarSLimits:
    """Limits from the grand mean and the mean subgroup standard deviation (3-sigma)."""
    k = c4(n)
    a3 = 3.0 / (k * math.sqrt(n))
    spread = 3.0 * math.sqrt(max(0.0, 1.0 - k * k)) / k
    return XbarSLimits(n=n, center=center, ucl=center + a3 * s_bar,
                       lcl=center - a3 * s_bar, s_center=s_bar,
                       s_ucl=(1.0 + spread) * s_bar, s_lcl=max(0.0, 1.0 - spread) * s_bar,
                       sigma_within=s_bar / k)


def limits_from_subgroups(subgroups: np.ndarray) -> XbarSLimits | None:
    """Limits from a baseline of subgroups (rows, all of one size >= 2); None without
    enough of them (fewer than two subgroups)."""
    x = np.asarray(subgroups, dtype=float)
    if x.ndim != 2 or x.shape[0] < 2 or x.shape[1] < 2:
        return None
    return xbar_s_limits(float(x.mean()), float(x.std(axis=1, ddof=1).mean()), x.shape[1])


@dataclass(frozen=True)
class Capability:
    """Capability indices against the specification limits, with 95 % confidence intervals
    (None where a limit or the spread is missing).

    ``cp``, ``cpk`` use the within-subgroup sigma; ``pp``, ``ppk`` the overall sample
    standard deviation.
    """

    n: int
    mean: float
    std_overall: float
    sigma_within: float
    cp: float | None
    cpk: float | None
    pp: float | None
    ppk: float | None
    cp_ci: tuple[float, float] | None
    cpk_ci: tuple[float, float] | None


def cp_interval(cp: float, n: int, confidence: float = 0.95) -> tuple[float, float]:
    """Confidence interval of Cp from ``n`` values (chi-square, Montgomery)."""
    nu = n - 1
    a = (1.0 - confidence) / 2.0
    # chdtri(nu, q): the chi-square quantile of upper tail q (scipy.stats.chi2.ppf(1 - q)).
    return (cp * math.sqrt(special.chdtri(nu, 1.0 - a) / nu),
            cp * math.sqrt(special.chdtri(nu, a) / nu))


def cpk_interval(cpk: float, n: int, confidence: float = 0.95) -> tuple[float, float]:
    """Approximate confidence interval of Cpk from ``n`` values (Bissell 1990)."""
    z = special.ndtri(1.0 - (1.0 - confidence) / 2.0)
    half = z * math.sqrt(1.0 / (9.0 * n) + cpk * cpk / (2.0 * (n - 1)))
    return cpk - half, cpk + half


def capability(values: Sequence[float], lsl: float | None, usl: float | None,
               sigma_within: float | None = None) -> Capability | None:
    """Cp, Cpk, Pp, Ppk of ``values`` (None for fewer than two values).

    ``sigma_within`` defaults to the overall standard deviation (then Cp = Pp).
    """
    x = np.asarray(values, dtype=float)
    x = x[np.isfinite(x)]
    n = x.size
    if n < 2:
        return None
    mean, s = float(x.mean()), float(x.std(ddof=1))
    sw = s if sigma_within is None else sigma_within

    def indices(sigma: float) -> tuple[float | None, float | None]:
        if not sigma > 0:
            return None, None
        cp = (usl - lsl) / (6 * sigma) if lsl is not None and usl is not None else None
        sides = [d for d in ((usl - mean) if usl is not None else None,
                             (mean - lsl) if lsl is not None else None) if d is not None]
        return cp, (min(sides) / (3 * sigma) if sides else None)

    cp, cpk = indices(sw)
    pp, ppk = indices(s)
    return Capability(n=n, mean=mean, std_overall=s, sigma_within=sw, cp=cp, cpk=cpk, pp=pp,
                      ppk=ppk, cp_ci=None if cp is None else cp_interval(cp, n),
                      cpk_ci=None if cpk is None else cpk_interval(cpk, n))


RULES = {
    1: "one point beyond 3 sigma",
    2: "nine points in a row on one side of the center line",
    3: "six points in a row steadily increasing or decreasing",
    4: "fourteen points in a row alternating up and down",
    5: "two of three points beyond 2 sigma on one side",
    6: "four of five points beyond 1 sigma on one side",
    7: "fifteen points in a row within 1 sigma",
    8: "eight points in a row beyond 1 sigma on either side",
}


@dataclass(frozen=True)
class RuleViolation:
    """Rule ``rule`` (``RULES``) fired at point ``index`` (the last point of its pattern)."""

    rule: int
    index: int

    @property
    def text(self) -> str:
        return RULES[self.rule]


def run_rules(zones: Sequence[float], rules: Sequence[int] = tuple(RULES)
              ) -> list[RuleViolation]:
    """Every point at which a rule fires, for points given as signed distances from the
    center line in sigmas of the plotted statistic (``XbarSLimits.zone``).

    A rule fires at a point when the pattern ending there is complete (Nelson's tests 1-8).
    """
    z = np.asarray(zones, dtype=float)
    return [RuleViolation(rule, i) for i in range(z.size)
            for rule in rules_at_end(z[:i + 1], rules)]


def rules_at_end(zones: Sequence[float], rules: Sequence[int] = tuple(RULES)
                 ) -> tuple[int, ...]:
    """The rules whose pattern ends at the last point (``run_rules`` for that point alone:
    what a live chart asks of each new point)."""
    z = np.asarray(zones, dtype=float)
    return tuple(rule for rule in rules if z.size and _fires(rule, z))


def _fires(rule: int, upto: np.ndarray) -> bool:
    """Whether ``rule``'s pattern ends at the last point of ``upto``."""

    def last(k: int) -> np.ndarray | None:
        return upto[-k:] if upto.size >= k else None

    if rule == 1:
        w = last(1)
        return bool(abs(w[0]) > 3)
    if rule == 2:
        w = last(9)
        return w is not None and (bool(np.all(w > 0)) or bool(np.all(w < 0)))
    if rule == 3:
        w = last(6)
        if w is None:
            return False
        d = np.diff(w)
        return bool(np.all(d > 0)) or bool(np.all(d < 0))
    if rule == 4:
        w = last(14)
        if w is None:
            return False
        d = np.sign(np.diff(w))
        return bool(np.all(d != 0)) and bool(np.all(d[1:] == -d[:-1]))
    if rule in (5, 6):
        k, need, beyond = (3, 2, 2.0) if rule == 5 else (5, 4, 1.0)
        w = last(k)
        if w is None or abs(w[-1]) <= beyond:
            return False  # the pattern ends with a point out there
        side = np.sign(w[-1])
        return int(np.sum(w * side > beyond)) >= need
    if rule == 7:
        w = last(15)
        return w is not None and bool(np.all(np.abs(w) < 1))
    if rule == 8:
        w = last(8)
        return w is not None and bool(np.all(np.abs(w) > 1))
    raise ValueError(f"no rule {rule}")
