"""``robust.median`` against numpy's, on the shapes and types the core gives it."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from service.measure.robust import median


@given(hnp.arrays(st.sampled_from([np.float64, np.float32, np.int64]),
                  hnp.array_shapes(min_dims=1, max_dims=2, min_side=1, max_side=40),
                  elements=st.integers(-1000, 1000)))
def test_median_is_numpys(values: np.ndarray) -> None:
    assert math.isclose(median(values), float(np.median(values)), rel_tol=1e-6, abs_tol=1e-6)


def test_median_of_nothing_is_nan() -> None:
    assert math.isnan(median(np.empty(0)))


def test_median_of_a_strided_view() -> None:
    a = np.arange(100.0).reshape(10, 10)[::3, ::2]
    assert median(a) == float(np.median(a))
