"""The first candidate path that may be proposed (eq. 23 in the RHC's order), with its loiter side."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from companion.core.geometry import FloatArray
from companion.core.safety.bounds import clause_out_of_reach, separated_from, separation_out_of_reach
from companion.core.safety.contingency import keeps_contingencies
from companion.core.safety.failsafe_regions import clears_loiters, leaves_loiters, loiter_clearance
from companion.core.safety.inputs import Candidates, Checked, Expanded, Regions, Rules
from companion.core.safety.separation import compatible, inside_fence, keeps_apart, split_crowded
from companion.core.search_area import spokes_clear


@njit(cache=True)
def first_allowed(
    candidates: Candidates, reference: Expanded, checked: Checked, regions: Regions, rules: Rules
) -> tuple[int, int]:
    """The first candidate path that may be proposed, and its loiter side.

    The first candidate path in `candidates.order` whose trajectory, with one of the loiter
    sides, stays in the fence, is compatible with everything `checked`, clears the others'
    contingency regions (`keeps_contingencies`) and the gone UAVs' `regions` (`clears_loiters`):
    (path, side +1 or -1); if none does, of those in the fence and compatible that may replace
    the trajectory in force `reference` (`keeps_contingencies`, `leaves_loiters`, and
    `keeps_apart` from the trajectories in force it is already too close to, `split_crowded`),
    the one farthest from what it does not clear; (-1, 0) if none. The side that turns towards
    `candidates.towards` at the plan's end is tried first (`Commitments._turn_towards`: away from
    a near UAV, else the region's centroid)."""
    separation, horizon = rules.separation, rules.horizon
    others, crowded, need = split_crowded(reference.pts, checked.others, checked.in_force, separation)
    loiters, paths, counts = regions
    pts = np.empty((candidates.shapes.shape[2], 2))
    known = np.full(checked.others.shape[0] + checked.lone.shape[0], np.nan)  # the reference's clearances
    hint = np.full(1, -1)  # the contingency region that failed the latest candidate
    # rows out of every candidate's reach are skipped before the exact tests (`bounds`)
    x, y, radius = candidates.x, candidates.y, candidates.radius
    clear = np.empty(others.shape[0], dtype=np.bool_)
    separation_out_of_reach(x, y, radius, others, separation, clear)
    far = np.empty(checked.others.shape[0], dtype=np.bool_)
    beyond = rules.reach + rules.disk_separation
    clause_out_of_reach(x, y, radius, candidates.centre_radius, checked.others, checked.centres, beyond, far)
    no_others = others[:0]
    best, best_side, farthest = -1, 0, -math.inf
    for i in candidates.order:
        first = _first_side(candidates, i, horizon)
        for side in (first, 1 - first):
            _place(candidates, i, side, pts)
            if not (
                inside_fence(pts, rules.normals, rules.offsets, rules.keepout)
                and separated_from(pts, others, clear, separation)
                and compatible(
                    pts,
                    no_others,
                    checked.disks,
                    checked.tethers,
                    checked.tether_disks,
                    separation,
                    rules.disk_separation,
                    rules.link,
                )
            ):
                continue
            cx, cy = _turned(candidates, candidates.centres[i, side, 0], candidates.centres[i, side, 1])
            if not spokes_clear(pts, horizon, cx, cy, rules.fan_keepout):
                continue
            code, worst = keeps_contingencies(
                Expanded(pts, horizon, cx, cy), reference, checked, rules, known, hint, far
            )
            apart, gap = keeps_apart(pts, crowded, need)
            if code == 0 or not apart:
                continue
            if (
                code == 2
                and crowded.shape[0] == 0
                and clears_loiters(
                    pts, loiters, paths, counts, rules.disk_separation, horizon, rules.progress
                )
            ):
                return i, 1 if side == 0 else -1
            if leaves_loiters(
                pts, reference.pts, loiters, paths, counts, rules.disk_separation, horizon, rules.progress
            ):
                clearance = min(worst, gap - separation, loiter_clearance(pts, loiters, paths, counts))
                if clearance > farthest:
                    farthest, best, best_side = clearance, i, 1 if side == 0 else -1
    return best, best_side


@njit(cache=True)
def _turned(candidates: Candidates, ox: float, oy: float) -> tuple[float, float]:
    """The point (ox, oy) relative to the candidates' anchor, turned by the heading and placed."""
    c = candidates
    return c.x + c.cos_h * ox - c.sin_h * oy, c.y + c.sin_h * ox + c.cos_h * oy


@njit(cache=True)
def _first_side(candidates: Candidates, i: int, horizon: int) -> int:
    """The loiter side to try first for path i: the one that turns towards `towards`.

    The loiter side to try first for path i (0: +1, 1: -1): the one that turns towards
    `candidates.towards` from the direction of the plan's last step."""
    c = candidates
    s0 = c.shapes[i, 0]
    ex = s0[horizon, 0] - s0[horizon - 1, 0]
    ey = s0[horizon, 1] - s0[horizon - 1, 1]
    ex, ey = c.cos_h * ex - c.sin_h * ey, c.sin_h * ex + c.cos_h * ey
    px, py = _turned(c, s0[horizon, 0], s0[horizon, 1])
    return 0 if ex * (c.towards[1] - py) - ey * (c.towards[0] - px) >= 0 else 1


@njit(cache=True)
def _place(candidates: Candidates, i: int, side: int, pts: FloatArray) -> None:
    """Write the trajectory of path i with loiter side `side` (0: +1, 1: -1), placed, into `pts`."""
    shape = candidates.shapes[i, side]
    for t in range(pts.shape[0]):
        pts[t, 0], pts[t, 1] = _turned(candidates, shape[t, 0], shape[t, 1])
