"""The type-1 gauge study (VDA 5 / ISO 22514-7 / AIAG MSA "Cg, Cgk"): one master measured
``n`` times by the gauge, against its certified value and the feature's tolerance.

Cg = (K/100 T) / (L s_g) and Cgk = (K/200 T - |bias|) / (L/2 s_g) with the usual K = 20 %
and L = 6: Cg = 0.2 T / (6 s_g), Cgk = (0.1 T - |bias|) / (3 s_g). The bias's t-test (is the
bias significantly non-zero?) and the resolution check (the gauge's resolution at most 5 % of
T). A gauge is capable when Cg and Cgk are at least 1.33 (the usual limit; a setting).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from scipy import special  # not scipy.stats: its import costs the service's start 0.5 s

MIN_VALUES = 25


@dataclass(frozen=True)
class GaugeStudy:
    """The figures of one type-1 study (lengths in the unit of the values, mm here)."""

    n: int
    reference: float
    tolerance: float
    mean: float
    bias: float
    s_g: float
    cg: float | None
    cgk: float | None
    t: float | None
    p_value: float | None
    bias_significant: bool | None
    resolution: float | None
    resolution_ok: bool | None
    capable: bool
    min_index: float
    reasons: tuple[str, ...]

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready (non-finite numbers as None)."""
        d = asdict(self)
        d["reasons"] = list(self.reasons)
        return {k: (None if isinstance(v, float) and not math.isfinite(v) else v)
                for k, v in d.items()}


def type1_study(values: Sequence[float], reference: float, tolerance: float,
                resolution: float | None = None, min_index: float = 1.33,
                alpha: float = 0.05, min_values: int = MIN_VALUES) -> GaugeStudy:
    """The study of ``values`` (at least ``min_values``) of a master certified at
    ``reference``, for a feature of tolerance ``tolerance`` (USL - LSL).

    Raises
    ------
    ValueError
        Too few values, or a tolerance that is not positive.
    """
    x = np.asarray(values, dtype=float)
    if x.size < min_values or not np.all(np.isfinite(x)):
        raise ValueError(f"a type-1 study needs at least {min_values} finite values, "
                         f"got {int(np.isfinite(x).sum())} of {x.size}")
    if not tolerance > 0:
        raise ValueError(f"the tolerance must be positive, got {tolerance!r}")
    n = int(x.size)
    mean = float(x.mean())
    s = float(x.std(ddof=1))
    bias = mean - reference
    if s > 0:
        cg = 0.2 * tolerance / (6.0 * s)
        cgk = (0.1 * tolerance - abs(bias)) / (3.0 * s)
        t = abs(bias) * math.sqrt(n) / s
        p = float(2.0 * special.stdtr(n - 1, -t))  # Student's t, both tails
    else:  # every value the same: no spread to judge (the resolution is too coarse)
        cg = cgk = t = p = None
    res_ok = None if resolution is None else bool(resolution <= 0.05 * tolerance)
    reasons = []
    if cg is None:
        reasons.append("no spread in the values: the resolution is too coarse to judge")
    else:
        if cg < min_index:
            reasons.append(f"Cg {cg:.2f} < {min_index:g}: repeatability too poor for the "
                           "tolerance")
        if cgk < min_index:
            reasons.append(f"Cgk {cgk:.2f} < {min_index:g}: bias and repeatability too large "
                           "for the tolerance")
    if res_ok is False:
        reasons.append(f"resolution {resolution:g} is more than 5 % of the tolerance")
    return GaugeStudy(
        n=n, reference=reference, tolerance=tolerance, mean=mean, bias=bias, s_g=s, cg=cg,
        cgk=cgk, t=t, p_value=p, bias_significant=None if p is None else bool(p < alpha),
        resolution=resolution, resolution_ok=res_ok, capable=not reasons,
        min_index=min_index, reasons=tuple(reasons))
