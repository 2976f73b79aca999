"""Diameter at the reference temperature of 20 C (ISO 1)."""

from __future__ import annotations

import math

STEEL_ALPHA_PER_K = 11.5e-6
REFERENCE_C = 20.0


def diameter_at_reference(diameter_mm: float, part_temp_c: float,
                          alpha_per_k: float = STEEL_ALPHA_PER_K,
                          reference_c: float = REFERENCE_C) -> float:
    """The diameter the part will have at 20 C.

    ``d20 = d / (1 + alpha (T - 20))``: a 50 mm steel shaft at 30 C reads about 5.75 um more
    than at 20 C.

    Parameters
    ----------
    diameter_mm : float
        Measured diameter at the part temperature, mm.
    part_temp_c : float
        Part temperature, degrees C.
    alpha_per_k : float
        Linear expansion coefficient, 1/K (steel 11.5e-6).
    reference_c : float
        Reference temperature, degrees C.

    Returns
    -------
    float
        Diameter at the reference temperature, mm.
    """
    if not (math.isfinite(part_temp_c) and -50.0 <= part_temp_c <= 300.0):
        raise ValueError(f"part temperature {part_temp_c} C is not plausible (-50 .. 300 C)")
    if not (math.isfinite(alpha_per_k) and 0 <= alpha_per_k < 1e-3):
        raise ValueError(f"expansion coefficient {alpha_per_k} 1/K is not plausible")
    return diameter_mm / (1.0 + alpha_per_k * (part_temp_c - reference_c))
