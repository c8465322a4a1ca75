"""The first candidate path that may be proposed (eq. 23 in the RHC's order), with its loiter side."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from companion.core.geometry import BoolArray, FloatArray, IntArray
from companion.core.safety.contingency import keeps_contingencies
from companion.core.safety.failsafe_regions import clears_loiters, leaves_loiters, loiter_clearance
from companion.core.safety.separation import compatible, inside_fence, keeps_apart, split_crowded


@njit(cache=True)
def first_allowed(
    order: IntArray,
    shapes: FloatArray,
    x: float,
    y: float,
    cos_h: float,
    sin_h: float,
    horizon: int,
    centre: FloatArray,
    normals: FloatArray,
    offsets: FloatArray,
    contingent: FloatArray,
    in_force: BoolArray,
    disks: FloatArray,
    tethers: FloatArray,
    tether_disks: FloatArray,
    fans: tuple[FloatArray, FloatArray, IntArray],
    progress: float,
    reference: FloatArray,
    reference_entry: int,
    centres_rel: FloatArray,
    entries: IntArray,
    centres: FloatArray,
    lone: FloatArray,
    lone_owners: IntArray,
    clause: BoolArray,
    reference_centre: FloatArray,
    reach: float,
    clearances: tuple[float, float, float],
) -> tuple[int, int]:
    """The first candidate path in `order` whose trajectory, with one of the loiter sides, stays in the
    fence, is compatible with everything given, clears the others' contingency regions
    (`keeps_contingencies` with the others' loiter `entries` and `centres`, the `lone` centres of
    `lone_owners`, the rows the `clause` holds against, and `reach`) and clears the regions `fans`
    (`clears_loiters`: their
    loiters, paths and path lengths, and `progress`): (path, side +1 or -1); if none does, of
    those in the fence and compatible that may replace the trajectory in force at `reference`
    (loiter entry `reference_entry`, centre `reference_centre`; `keeps_contingencies`,
    `leaves_loiters`, and `keeps_apart` from the trajectories in force it is already too close to,
    `split_crowded`), the one farthest from what it does not clear; (-1, 0) if none.
    `contingent` are the others' trajectories (those `in_force` and proposals) to be compatible
    with and whose failsafe regions to clear.
    `shapes` (n_paths, 2 sides, window + 1, 2) holds the trajectories relative to their anchor
    (`Limits.shapes`) and `centres_rel` (n_paths, 2 sides, 2) their loiter centres, placed at (x, y)
    and turned by the heading (cos_h, sin_h). The side that turns towards `centre` at the plan's
    end is tried first (`Commitments._turn_towards`: away from a near UAV, else the region's
    centroid)."""
    separation, disk_separation, link = clearances
    others, crowded, need = split_crowded(reference, contingent, in_force, separation)
    width = shapes.shape[2]
    pts = np.empty((width, 2))
    known = np.full(contingent.shape[0] + lone.shape[0], np.nan)  # the reference's clearances
    hint = np.full(1, -1)  # the contingency region that failed the latest candidate
    best, best_side, farthest = -1, 0, -math.inf
    for i in order:
        s0 = shapes[i, 0]
        ex = s0[horizon, 0] - s0[horizon - 1, 0]
        ey = s0[horizon, 1] - s0[horizon - 1, 1]
        ex, ey = cos_h * ex - sin_h * ey, sin_h * ex + cos_h * ey
        px = x + cos_h * s0[horizon, 0] - sin_h * s0[horizon, 1]
        py = y + sin_h * s0[horizon, 0] + cos_h * s0[horizon, 1]
        first = 0 if ex * (centre[1] - py) - ey * (centre[0] - px) >= 0 else 1
        for side in (first, 1 - first):
            for t in range(width):
                ox, oy = shapes[i, side, t, 0], shapes[i, side, t, 1]
                pts[t, 0] = x + cos_h * ox - sin_h * oy
                pts[t, 1] = y + sin_h * ox + cos_h * oy
            if not (
                inside_fence(pts, normals, offsets)
                and compatible(pts, others, disks, tethers, tether_disks, separation, disk_separation, link)
            ):
                continue
            ox, oy = centres_rel[i, side, 0], centres_rel[i, side, 1]
            code, worst = keeps_contingencies(
                pts,
                horizon,
                x + cos_h * ox - sin_h * oy,
                y + sin_h * ox + cos_h * oy,
                reference,
                reference_entry,
                reference_centre[0],
                reference_centre[1],
                contingent,
                entries,
                centres,
                lone,
                lone_owners,
                clause,
                reach,
                disk_separation,
                known,
                hint,
            )
            apart, gap = keeps_apart(pts, crowded, need)
            if code == 0 or not apart:
                continue
            if (
                code == 2
                and crowded.shape[0] == 0
                and clears_loiters(pts, *fans, disk_separation, horizon, progress)
            ):
                return i, 1 if side == 0 else -1
            if leaves_loiters(pts, reference, *fans, disk_separation, horizon, progress):
                clearance = min(worst, gap - separation, loiter_clearance(pts, *fans))
                if clearance > farthest:
                    farthest, best, best_side = clearance, i, 1 if side == 0 else -1
    return best, best_side
