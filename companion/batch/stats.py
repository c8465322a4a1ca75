"""Interval estimates for paired comparisons: a mean of paired differences and a proportion.

The mean has a Student t interval, the proportion a Wilson score interval.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy import stats


@dataclass(frozen=True)
class Interval:
    """An estimate with its two-sided confidence interval [low, high] from n observations."""

    estimate: float
    low: float
    high: float
    n: int


def mean_ci(values: ArrayLike, confidence: float = 0.95) -> Interval:
    """The mean of `values` (paired differences, say) and its Student t interval.

    With one value the interval is unbounded (NaN).
    """
    x = np.asarray(values, dtype=float).ravel()
    n = len(x)
    if n == 0:
        raise ValueError("no values to estimate a mean from")
    mean = float(x.mean())
    if n == 1:
        return Interval(mean, math.nan, math.nan, 1)
    half = float(stats.t.ppf((1 + confidence) / 2, n - 1) * x.std(ddof=1) / math.sqrt(n))
    return Interval(mean, mean - half, mean + half, n)


def wilson(successes: int, n: int, confidence: float = 0.95) -> Interval:
    """The proportion successes / n and its Wilson score interval."""
    if n <= 0 or not 0 <= successes <= n:
        raise ValueError(f"need 0 <= successes <= n and n > 0, got {successes} of {n}")
    z = float(stats.norm.ppf((1 + confidence) / 2))
    p = successes / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z / (1 + z * z / n) * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    return Interval(p, max(0.0, centre - half), min(1.0, centre + half), n)
