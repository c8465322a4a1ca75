"""The contingency clause: each of two trajectories keeps clear of the other's failsafe fan."""

from __future__ import annotations

import math

from numba import njit

from companion.core.geometry import BoolArray, FloatArray, IntArray
from companion.core.safety.fans import fan_clearance, fan_count, fan_radius, to_segment
from companion.core.trajectory import point_clearance


@njit(cache=True)
def _clearly_clear(
    pts: FloatArray,
    count: int,
    cx: float,
    cy: float,
    other: FloatArray,
    other_count: int,
    ox: float,
    oy: float,
    beyond: float,
) -> bool:
    """Whether `contingency_clearance` is certainly above `beyond`, from the disks about the centres
    that hold the fans (cheap: most pairs are far apart)."""
    mine = point_clearance(pts, ox, oy) - fan_radius(other, other_count, ox, oy)
    theirs = point_clearance(other, cx, cy) - fan_radius(pts, count, cx, cy)
    return min(mine, theirs) > beyond


@njit(cache=True)
def contingency_clearance(
    pts: FloatArray,
    entry: int,
    cx: float,
    cy: float,
    other: FloatArray,
    other_entry: int,
    ox: float,
    oy: float,
    reach: float,
) -> float:
    """How far each of two trajectories (positions `pts` and `other` over the same steps, loiter
    entry indices `entry` and `other_entry`, loiter centres (cx, cy) and (ox, oy)) keeps from the
    region where the other UAV's aircraft may fly if its companion falls silent now or later: the
    other's fan (`fan_clearance`: its path from now to its loiter, spoked to the loiter's centre)
    inflated by `reach`; the smaller of the two."""
    width = pts.shape[0]
    mine = fan_clearance(pts, other, fan_count(other_entry, width), ox, oy)
    theirs = fan_clearance(other, pts, fan_count(entry, width), cx, cy)
    return min(mine, theirs) - reach


@njit(cache=True)
def keeps_contingencies(
    pts: FloatArray,
    entry: int,
    cx: float,
    cy: float,
    reference: FloatArray,
    reference_entry: int,
    rx: float,
    ry: float,
    others: FloatArray,
    entries: IntArray,
    centres: FloatArray,
    lone: FloatArray,
    lone_owners: IntArray,
    clause: BoolArray,
    reach: float,
    disk_separation: float,
    known: FloatArray,
    hint: IntArray,
) -> tuple[int, float]:
    """The contingency clause of compatibility for the trajectory at `pts` (loiter entry index
    `entry`, loiter centre (cx, cy)), against the others' trajectories at `others` (loiter entries
    `entries`, centres `centres`) and the loiter centres `lone` of the trajectories in force a UAV
    announced before its latest (its failsafe may still circle there, reached along its trajectory
    in force, others[lone_owners]; one-sided), where `clause` holds for the row (its owner's layer
    is near; other rows are cleared vertically): 2 if it clears every such region by more than
    `disk_separation` (`contingency_clearance`); else 1 if, against every region it does not clear,
    it keeps at least as far as the trajectory in force at `reference` (`reference_entry`, loiter
    centre (rx, ry)) over the same steps (a start layout closer than the clause: pairs only move
    apart); else 0. Also the smallest clearance of a pair it does not clear (infinite if none; with
    0, the clearance from a region it keeps less far from than the reference).
    Between calls with the same reference (`first_allowed`'s candidates), `known` (an entry per row
    of `others`, then per `lone` centre; NaN until computed) keeps the reference's clearances, and
    hint[0] the entry that failed last (-1: none), which is tried first: the answer is 0 as soon as
    any entry fails, whichever it is."""
    args = (pts, entry, cx, cy, reference, reference_entry, rx, ry, others, entries, centres)
    more = (lone, lone_owners, clause, reach, disk_separation, known)
    if hint[0] >= 0:
        state, c = _against(hint[0], *args, *more)
        if state == 0:
            return 0, c
    code, worst = 2, math.inf
    for o in range(others.shape[0] + lone.shape[0]):
        state, c = _against(o, *args, *more)
        if state == 0:
            hint[0] = o
            return 0, c
        if state == 1:
            code, worst = 1, min(worst, c)
    return code, worst


@njit(cache=True)
def _against(
    o: int,
    pts: FloatArray,
    entry: int,
    cx: float,
    cy: float,
    reference: FloatArray,
    reference_entry: int,
    rx: float,
    ry: float,
    others: FloatArray,
    entries: IntArray,
    centres: FloatArray,
    lone: FloatArray,
    lone_owners: IntArray,
    clause: BoolArray,
    reach: float,
    disk_separation: float,
    known: FloatArray,
) -> tuple[int, float]:
    """`keeps_contingencies` against its entry o (a row of `others`, then a `lone` centre): 2 it
    clears the region, 1 it does not but keeps as far as the reference (and its clearance), 0 it
    keeps less far."""
    width = pts.shape[0]
    if o < others.shape[0]:
        if not clause[o]:
            return 2, math.inf
        ox, oy, oe = centres[o, 0], centres[o, 1], entries[o]
        count, other_count = fan_count(entry, width), fan_count(oe, width)
        if _clearly_clear(pts, count, cx, cy, others[o], other_count, ox, oy, reach + disk_separation):
            return 2, math.inf
        # the pair's clearance, min(mine, theirs) - reach (`contingency_clearance`), is at most mine,
        # which is at most the clearance from the other's loiter centre (`_centre_clearance`): a
        # trajectory closer than the reference to the other's region fails without the fans
        reference_pair = (reference, reference_entry, rx, ry, others, entries, centres, reach)
        near = _centre_clearance(pts, ox, oy) - reach
        if near <= disk_separation and near < _reference_clearance(known, o, *reference_pair):
            return 0, near
        mine = fan_clearance(pts, others[o], other_count, ox, oy) - reach
        if mine <= disk_separation and mine < _reference_clearance(known, o, *reference_pair):
            return 0, mine
        c = min(mine, fan_clearance(others[o], pts, count, cx, cy) - reach)
        if c > disk_separation:
            return 2, math.inf
        return (0 if c < _reference_clearance(known, o, *reference_pair) else 1), c
    lo = o - others.shape[0]
    owner = lone_owners[lo]
    flown = fan_count(entries[owner], width)
    lx, ly = lone[lo, 0], lone[lo, 1]
    if point_clearance(pts, lx, ly) - fan_radius(others[owner], flown, lx, ly) - reach > disk_separation:
        return 2, math.inf
    c = fan_clearance(pts, others[owner], flown, lx, ly) - reach
    if c > disk_separation:
        return 2, math.inf
    if math.isnan(known[o]):
        known[o] = fan_clearance(reference, others[owner], flown, lx, ly) - reach
    return (0 if c < known[o] else 1), c


@njit(cache=True)
def _centre_clearance(a: FloatArray, cx: float, cy: float) -> float:
    """The closest approach of the chords of `a` to (cx, cy), computed as `fan_clearance` does for
    the fan's centre: never below `fan_clearance(a, ..., cx, cy)`, to the last bit."""
    best = math.inf
    for t in range(a.shape[0] - 1):
        best = min(best, to_segment(cx, cy, a[t, 0], a[t, 1], a[t + 1, 0], a[t + 1, 1]))
    return best


@njit(cache=True)
def _reference_clearance(
    known: FloatArray,
    o: int,
    reference: FloatArray,
    reference_entry: int,
    rx: float,
    ry: float,
    others: FloatArray,
    entries: IntArray,
    centres: FloatArray,
    reach: float,
) -> float:
    """`contingency_clearance` of the reference and others[o], computed once (`keeps_contingencies`)."""
    if math.isnan(known[o]):
        other, ox, oy = others[o], centres[o, 0], centres[o, 1]
        known[o] = contingency_clearance(reference, reference_entry, rx, ry, other, entries[o], ox, oy, reach)
    return known[o]
