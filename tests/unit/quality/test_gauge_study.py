"""The type-1 gauge study: the AIAG MSA bias example, the definitions, and properties."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from service.quality.gauge_study import type1_study

# AIAG, Measurement Systems Analysis, 4th edition (2010), chapter III, "Bias - Independent
# Sample Method", example: a part of reference value 6.00 measured 15 times.
AIAG_VALUES = [5.8, 5.7, 5.9, 5.9, 6.0, 6.1, 6.0, 6.1, 6.4, 6.3, 6.0, 6.1, 6.2, 5.6, 6.0]


def test_the_aiag_bias_example() -> None:
    # AIAG's figures: mean 6.0067, bias .0067, sigma_r .2120, t .1215 (from rounded
    # intermediates; unrounded it is .1218), 14 degrees of freedom: the bias is not
    # significant at alpha .05.
    study = type1_study(AIAG_VALUES, 6.00, tolerance=2.0, min_values=15)
    assert study.mean == pytest.approx(6.0067, abs=5e-5)
    assert study.bias == pytest.approx(0.0067, abs=5e-5)
    assert study.s_g == pytest.approx(0.2120, abs=5e-5)
    assert study.t == pytest.approx(0.1215, abs=5e-4)
    assert study.bias_significant is False
    assert study.p_value == pytest.approx(0.905, abs=0.005)


def test_cg_and_cgk_by_their_definition() -> None:
    rng = np.random.default_rng(5)
    x = 30.0 + 0.0006 + rng.normal(0, 0.0008, 50)
    s = x.std(ddof=1)
    study = type1_study(x, 30.0, 0.04, resolution=0.0001)
    assert study.cg == pytest.approx(0.2 * 0.04 / (6 * s))
    assert study.cgk == pytest.approx((0.004 - abs(x.mean() - 30.0)) / (3 * s))
    assert study.capable and study.resolution_ok and study.reasons == ()


def test_an_incapable_gauge_says_why() -> None:
    rng = np.random.default_rng(6)
    study = type1_study(30.0 + rng.normal(0.003, 0.002, 50), 30.0, 0.04, resolution=0.005)
    assert not study.capable
    assert any(r.startswith("Cgk") for r in study.reasons)
    assert any("resolution" in r for r in study.reasons)
    assert study.bias_significant is True


def test_refusals() -> None:
    with pytest.raises(ValueError, match="at least 25"):
        type1_study([30.0] * 24, 30.0, 0.04)
    with pytest.raises(ValueError, match="positive"):
        type1_study([30.0] * 25, 30.0, 0.0)
    flat = type1_study([30.0] * 25, 30.0, 0.04)
    assert flat.cg is None and not flat.capable


values = st.lists(st.floats(-0.01, 0.01, allow_nan=False), min_size=25, max_size=60).filter(
    lambda v: np.std(v) > 1e-6)


@given(values, st.floats(0.005, 0.2))
def test_cgk_never_exceeds_cg(v: list[float], tol: float) -> None:
    study = type1_study(np.array(v) + 30.0, 30.0, tol)
    assert study.cgk <= study.cg + 1e-9


@given(values, st.floats(0.01, 0.2), st.floats(0.01, 100.0))
def test_scale_invariance(v: list[float], tol: float, k: float) -> None:
    a = type1_study(np.array(v) + 30.0, 30.0, tol)
    b = type1_study((np.array(v) + 30.0) * k, 30.0 * k, tol * k)
    assert b.cg == pytest.approx(a.cg, rel=1e-6)
    assert b.cgk == pytest.approx(a.cgk, rel=1e-6, abs=1e-9)


@given(st.floats(0.01, 0.2), st.integers(0, 2**32 - 1))
def test_a_bias_of_a_tenth_of_the_tolerance_gives_cgk_zero(tol: float, seed: int) -> None:
    e = np.random.default_rng(seed).normal(0, 1, 40)
    e = (e - e.mean()) / e.std(ddof=1) * tol / 100  # mean exactly 0
    study = type1_study(30.0 + 0.1 * tol + e, 30.0, tol)
    assert study.cgk == pytest.approx(0.0, abs=1e-6)
