"""The imperfect detector: Pd falling with distance, false alarms, and each look's log-likelihood ratio.

A look is one sampling moment's picture of one cell in the FOV (eq. 3). A target in the cell is
reported with probability Pd(d), falling linearly from `pd` under the UAV to `pd_edge` at R_A; an
empty cell is reported (a false alarm) with probability `pf`. Looks are independent. The draws
are a pure function of (seed, run, UAV, step, cell), so the batch engine and the companion's
camera report the same misses and false alarms for the same look, whatever else they draw.

The log-likelihood ratio of a look (`look_llr`) is rounded to a multiple of 2^-20 and capped at
+-LLR_CAP: sums of such numbers are exact in float64, so a posterior in log-odds is the same
whatever order the looks were added in (`core.belief`).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from companion.core.geometry import FloatArray, IntArray

LLR_CAP = 40.0  # a perfect detector's look: odds of e^40 either way
LLR_QUANTUM = 2.0**-20


class SensorModel(NamedTuple):
    """Pd under the UAV and at R_A, the false-alarm chance per look per empty cell, and R_A."""

    pd: float
    pd_edge: float
    pf: float
    radius: float

    @property
    def perfect(self) -> bool:
        """Pd = 1 everywhere and Pf = 0: the paper's camera."""
        return self.pd == 1.0 and self.pd_edge == 1.0 and self.pf == 0.0


@njit(cache=True)
def detection_probability(distance: float, pd: float, pd_edge: float, radius: float) -> float:
    """Pd(d) = pd + (pd_edge - pd) d / R_A, clipped to the FOV (d in [0, R_A])."""
    f = min(max(distance / radius, 0.0), 1.0) if radius > 0 else 0.0
    return pd + (pd_edge - pd) * f


@njit(cache=True)
def quantized(x: float) -> float:
    """x capped at +-LLR_CAP and rounded to a multiple of LLR_QUANTUM (sums stay exact)."""
    x = min(max(x, -LLR_CAP), LLR_CAP)
    return round(x / LLR_QUANTUM) * LLR_QUANTUM


@njit(cache=True)
def _log_ratio(num: float, den: float) -> float:
    if num <= 0.0:
        return -LLR_CAP
    if den <= 0.0:
        return LLR_CAP
    return math.log(num / den)


@njit(cache=True)
def look_llr(hit: bool, distance: float, pd: float, pd_edge: float, pf: float, radius: float) -> float:
    """Bayes' rule for one look: log P(report | target) / P(report | empty), quantized.

    A hit: log(Pd(d) / Pf); a miss: log((1 - Pd(d)) / (1 - Pf))."""
    p = detection_probability(distance, pd, pd_edge, radius)
    if hit:
        return quantized(_log_ratio(p, pf))
    return quantized(_log_ratio(1.0 - p, 1.0 - pf))


@njit(cache=True)
def _mix(z: np.uint64) -> np.uint64:
    """splitmix64's finaliser: a bijection of 64-bit words that scrambles every bit."""
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))


@njit(cache=True)
def look_uniform(seed: int, run: int, uav: int, step: int, cell: int) -> float:
    """A uniform draw in [0, 1) that depends only on (seed, run, uav, step, cell)."""
    golden = np.uint64(0x9E3779B97F4A7C15)
    z = np.uint64(0)
    for part in (seed, run, uav, step, cell):
        z = _mix(z + golden + np.uint64(part & 0xFFFFFFFFFFFF))
    return float(z >> np.uint64(11)) * (1.0 / 9007199254740992.0)


@njit(cache=True)
def draw_reports(
    seed: int,
    run: int,
    uav: int,
    step: int,
    cells: IntArray,
    distances: FloatArray,
    holds_target: np.ndarray,
    model: tuple[float, float, float, float],
) -> np.ndarray:
    """Which of the looked-at `cells` the detector reports as holding a target.

    A cell holding a target (`holds_target[cell]`) is reported when its draw falls below
    Pd(distance), an empty one when it falls below Pf."""
    pd, pd_edge, pf, radius = model
    out = np.zeros(cells.shape[0], dtype=np.bool_)
    for i in range(cells.shape[0]):
        u = look_uniform(seed, run, uav, step, cells[i])
        if holds_target[cells[i]]:
            out[i] = u < detection_probability(distances[i], pd, pd_edge, radius)
        else:
            out[i] = u < pf
    return out


def sensor_model(pd: float, pd_edge: float | None, pf: float, radius: float) -> SensorModel:
    """The `SensorModel` of a mission's sensor table (pd_edge defaults to pd)."""
    return SensorModel(pd, pd if pd_edge is None else pd_edge, pf, radius)


@njit(cache=True)
def with_reports(looked: IntArray, reported: IntArray) -> tuple[IntArray, np.ndarray]:
    """One picture's looks: the cells in view and those reported (-1: outside every cell), and the hits.

    The sorted union of `looked` and the reported cells (a report from the camera's own position
    outside the FOV is a look at its cell too), and which of them were reported."""
    hit = np.unique(reported[reported >= 0])
    cells = np.unique(np.concatenate((looked, hit)))
    hits = np.zeros(cells.shape[0], dtype=np.bool_)
    j = 0
    for i in range(cells.shape[0]):
        while j < hit.shape[0] and hit[j] < cells[i]:
            j += 1
        hits[i] = j < hit.shape[0] and hit[j] == cells[i]
    return cells, hits


@njit(cache=True)
def reported_cells(
    centres: FloatArray,
    cells: IntArray,
    holds_target: np.ndarray,
    model: tuple[float, float, float, float],
    look: tuple[int, int, int, int],
    at: tuple[float, float],
) -> IntArray:
    """The `cells` in view that the detector reports, for look (seed, run, uav, step) from `at`.

    `at` is the UAV's position (x, y); `draw_reports` decides each cell at the distance from `at`
    to its centre."""
    distances = np.empty(cells.shape[0])
    for i in range(cells.shape[0]):
        distances[i] = math.hypot(centres[cells[i], 0] - at[0], centres[cells[i], 1] - at[1])
    seed, run, uav, step = look
    return cells[draw_reports(seed, run, uav, step, cells, distances, holds_target, model)]
