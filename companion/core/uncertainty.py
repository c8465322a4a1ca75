"""Uncertainty map (eqs. 10-11) and importance (eq. 12)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numba import njit

from companion.core.geometry import FloatArray, IntArray


@njit(cache=True)
def apply_looks(eta: FloatArray, cells: IntArray, gamma: float) -> None:
    """Eqs. 10-11 in place: eta_p <- gamma^h_p * eta_p, h_p = number of times p occurs in `cells`.

    `cells` concatenates the FOV cells of this UAV and of every neighbour heard this step
    (a homogeneous swarm: gamma_j = gamma); indices outside [0, len(eta)) are padding and ignored.
    """
    n = eta.shape[0]
    for c in cells:
        if 0 <= c < n:
            eta[c] *= gamma


@njit(cache=True)
def mark_seen(seen: np.ndarray, covered: IntArray, labels: IntArray, cells: IntArray) -> int:
    """Record first looks: `seen[p]` turns True and the covered-cell count of p's task grows (eq. 20).

    `covered` may be empty (no tasks); `labels[p]` is the task of cell p. Returns the number of
    cells seen for the first time.
    """
    n, new = seen.shape[0], 0
    for c in cells:
        if 0 <= c < n and not seen[c]:
            seen[c] = True
            new += 1
            if covered.shape[0] > 0:
                covered[labels[c]] += 1
    return new


@njit(cache=True)
def look_map(
    eta: FloatArray, gamma: float, seen: np.ndarray, covered: IntArray, labels: IntArray, cells: IntArray
) -> None:
    """`apply_looks` then `mark_seen` for the FOV cells `cells`, in one call."""
    apply_looks(eta, cells, gamma)
    mark_seen(seen, covered, labels, cells)


def importance(eta: FloatArray, prior: FloatArray) -> FloatArray:
    """Eq. 12: s_p = eta_p * Pr_p."""
    return eta * prior


def global_average_uncertainty(etas: Sequence[FloatArray]) -> float:
    """Eq. 30: mean over UAVs and cells of eta_{i,p,k} (one map per UAV)."""
    return sum(float(np.add.reduce(e)) for e in etas) / sum(e.size for e in etas)
