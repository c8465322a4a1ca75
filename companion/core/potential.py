"""Connectivity and collision barriers: the communication cost of eq. 17 and the virtual force of eq. 28.

Both are `exp(max(0, ratio)) - 1` terms that are zero inside a comfortable band and grow without
bound towards a hard limit (R_c for the link, R_s for safety). Beyond the limit the paper calls the
cost prohibitive; here the exponent is capped at `EXPONENT_CAP` near the limit and keeps growing
linearly past it, so that a disconnected or too-close pair still prefers the move that helps most.
The cap (e^30, about 1e13) keeps every barrier above any search benefit or region penalty.
The functions are numba ufuncs: they take scalars or arrays, from Python or from compiled kernels.
"""

from __future__ import annotations

import math

from numba import vectorize

EXPONENT_CAP = 30.0


@vectorize(["float64(float64, float64, float64)"], cache=True)
def link_cost(d: float, r_c: float, r_c_attr: float) -> float:
    """exp(max(0, (d - R'_c) / (R_c - d))) - 1: zero below R'_c, unbounded as d -> R_c (eqs. 17, 28)."""
    if d >= r_c:
        exponent = EXPONENT_CAP + (d - r_c) / (r_c - r_c_attr)
    else:
        exponent = min(max((d - r_c_attr) / (r_c - d), 0.0), EXPONENT_CAP)
    return math.expm1(min(exponent, 700.0))


@vectorize(["float64(float64, float64, float64)"], cache=True)
def safety_cost(d: float, r_s: float, r_s_rep: float) -> float:
    """exp(max(0, (R'_s - d) / (d - R_s))) - 1: zero above R'_s, unbounded as d -> R_s (eq. 28)."""
    if d <= r_s:
        exponent = EXPONENT_CAP + (r_s - d) / (r_s_rep - r_s)
    else:
        exponent = min(max((r_s_rep - d) / (d - r_s), 0.0), EXPONENT_CAP)
    return math.expm1(min(exponent, 700.0))


@vectorize(["float64(float64, float64, float64, float64, float64)"], cache=True)
def virtual_force(d: float, r_c: float, r_c_attr: float, r_s: float, r_s_rep: float) -> float:
    """Eq. 28: F = attraction + repulsion, zero in the band [R'_s, R'_c]."""
    return link_cost(d, r_c, r_c_attr) + safety_cost(d, r_s, r_s_rep)
