"""The regions where gone UAVs' aircraft fly: keeping clear of them, or leaving them."""

from __future__ import annotations

import math

from numba import njit

from companion.core.geometry import FloatArray, IntArray
from companion.core.safety.fans import fan_clearance


@njit(cache=True)
def clears_loiters(
    pts: FloatArray,
    loiters: FloatArray,
    paths: FloatArray,
    counts: IntArray,
    disk_separation: float,
    horizon: int,
    progress: float,
) -> bool:
    """Whether a trajectory keeps clear of every region where a silent UAV's aircraft flies.

    Whether the trajectory at `pts` (window + 1 positions, its M = `horizon` planned steps first)
    keeps clear of every region where a silent UAV's aircraft flies (`Commitments`): the fan of
    paths[d][:counts[d]] about (cx, cy) of loiters[d] = (cx, cy, r), inflated by r (a disk where
    counts[d] is 0): either it is out of the region, farther than `disk_separation` from it, from
    some step on and for good (its loiter repeats within the window), or it starts within that
    distance and every planned step takes it at least `progress` farther from the fan (a UAV deep
    inside cannot get out within one plan: it gets out plan by plan)."""
    for d in range(loiters.shape[0]):
        cx, cy, r = loiters[d, 0], loiters[d, 1], loiters[d, 2]
        path, count = paths[d], counts[d]
        out = -1
        for t in range(pts.shape[0]):
            if fan_clearance(pts[t : t + 1], path, count, cx, cy) - r > disk_separation:
                out = t
                break
        if out >= 0 and fan_clearance(pts[out:], path, count, cx, cy) - r > disk_separation:
            continue
        if out == 0:
            return False
        for t in range(horizon):
            before = fan_clearance(pts[t : t + 1], path, count, cx, cy)
            if fan_clearance(pts[t + 1 : t + 2], path, count, cx, cy) < before + progress:
                return False
    return True


@njit(cache=True)
def loiter_clearance(pts: FloatArray, loiters: FloatArray, paths: FloatArray, counts: IntArray) -> float:
    """The trajectory's closest approach to the nearest region of `clears_loiters`.

    The trajectory's closest approach over the window to the nearest of the regions of
    `clears_loiters`: negative inside one, infinite without any."""
    best = math.inf
    for d in range(loiters.shape[0]):
        cx, cy = loiters[d, 0], loiters[d, 1]
        best = min(best, fan_clearance(pts, paths[d], counts[d], cx, cy) - loiters[d, 2])
    return best


@njit(cache=True)
def leaves_loiters(
    pts: FloatArray,
    reference: FloatArray,
    loiters: FloatArray,
    paths: FloatArray,
    counts: IntArray,
    disk_separation: float,
    horizon: int,
    progress: float,
) -> bool:
    """Whether a trajectory may replace the one in force near regions it does not clear.

    Whether the trajectory at `pts` may replace the one in force at `reference` (the same steps)
    near the regions of `clears_loiters`: for each, it clears it, or its closest approach to the
    region's fan over the window is larger than the reference's. Where nothing that clears them
    all is flyable (a UAV boxed in by the fence and its neighbours), flying it keeps the UAV
    farther from each silent UAV's aircraft than flying on would, and the next plan starts from
    there."""
    for d in range(loiters.shape[0]):
        one = loiters[d : d + 1]
        if clears_loiters(pts, one, paths[d : d + 1], counts[d : d + 1], disk_separation, horizon, progress):
            continue
        cx, cy, path, count = loiters[d, 0], loiters[d, 1], paths[d], counts[d]
        if fan_clearance(pts, path, count, cx, cy) <= fan_clearance(reference, path, count, cx, cy):
            return False
    return True
