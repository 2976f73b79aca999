"""Robust statistics of a frame's few hundred values, without numpy's per-call overhead.

``np.median`` costs about 19 us whatever the length (a copy, NaN checks, a mean of two); a
tracked frame takes nine medians of a few hundred values. Selecting the rows of a 2-D array
by a boolean mask costs 8 us for 500 rows, by ``take`` of their indices under 1 us. Pure; no
I/O.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["median", "row_index", "rows"]


def median(values: np.ndarray) -> float:
    """The median of all ``values`` (any shape, flattened), as ``np.median`` gives it; NaN
    when there are none. NaNs are not looked for: the callers' values are finite."""
    a = np.asarray(values).ravel()
    n = a.size
    if n == 0:
        return math.nan
    k = n // 2
    if n % 2:
        return float(np.partition(a, k)[k])
    part = np.partition(a, (k - 1, k))
    return 0.5 * (float(part[k - 1]) + float(part[k]))


def row_index(keep: np.ndarray) -> np.ndarray:
    """The indices a boolean mask selects (an index array as it is), for ``rows``."""
    return np.flatnonzero(keep) if keep.dtype == np.bool_ else keep


def rows(a: np.ndarray, index: np.ndarray) -> np.ndarray:
    """``a[index]`` for an index array (``row_index``), without boolean indexing's cost."""
    return a.take(index, axis=0)
