"""Prior target probability map (eq. 1)."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from companion.core.geometry import FloatArray


def gain_for_peak(peak: float, sigma: float) -> float:
    """K_z such that the centre's own term of eq. 1 equals `peak` at the centre."""
    return peak * math.sqrt(2.0 * math.pi) * sigma


def centre_probability(centres: FloatArray, centre: Sequence[float], gain: float, sigma: float) -> FloatArray:
    """Eq. 1, one centre: Pr_{p,z} = K_z / (sqrt(2 pi) sigma) * exp(-||mu_z - mu_p||^2 / (2 sigma^2))."""
    d2 = np.sum((centres - np.asarray(centre, dtype=float)) ** 2, axis=1)
    return gain / (math.sqrt(2.0 * math.pi) * sigma) * np.exp(-d2 / (2.0 * sigma**2))


def prior_map(
    centres: FloatArray,
    distribution_centres: Sequence[tuple[float, float, float] | tuple[float, float, float, float | None]],
    sigma: float,
) -> FloatArray:
    """Eq. 1, combined: Pr_p = 1 - prod_z (1 - Pr_{p,z}), the chance that cell p holds a target.

    `distribution_centres` holds (x, y, peak) or (x, y, peak, sigma_z) per centre: a centre's own
    sigma_z replaces the common `sigma`; peak <= 1 keeps every term a probability.
    """
    miss = np.ones(centres.shape[0])
    for x, y, peak, *own in distribution_centres:
        s = own[0] if own and own[0] is not None else sigma
        miss *= 1.0 - centre_probability(centres, (x, y), gain_for_peak(peak, s), s)
    return 1.0 - miss


def draw_targets(prior: FloatArray, count: int, rng: np.random.Generator) -> np.ndarray:
    """Ground-truth target cells: `count` distinct cells drawn with probability proportional to Pr_p."""
    count = min(count, int(np.count_nonzero(prior > 0)))
    return np.sort(rng.choice(prior.shape[0], size=count, replace=False, p=prior / prior.sum()))
