"""The contingency clause: each of two trajectories keeps clear of the other's failsafe fan."""

from __future__ import annotations

import math

from numba import njit

from companion.core.geometry import BoolArray, FloatArray, IntArray
from companion.core.safety.fans import fan_clearance, fan_count, fan_radius, to_segment
from companion.core.safety.inputs import Checked, Expanded, Rules
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
    """Whether the pair surely clears the clause, judged from the disks that hold the fans.

    Whether `contingency_clearance` is certainly above `beyond`, from the disks about the centres
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
    """The clearance of two trajectories from each other's failsafe fans, the smaller of the two.

    How far each of two trajectories (positions `pts` and `other` over the same steps, loiter
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
    mine: Expanded,
    reference: Expanded,
    checked: Checked,
    rules: Rules,
    known: FloatArray,
    hint: IntArray,
    far: BoolArray,
) -> tuple[int, float]:
    """The contingency clause: whether a trajectory clears the others' failsafe regions.

    The contingency clause of compatibility for the trajectory `mine`, against the others'
    trajectories (`checked.others`, their loiter entries and centres) and the loiter centres
    `checked.lone` of the trajectories in force a UAV announced before its latest (its failsafe
    may still circle there, reached along its trajectory in force, others[lone_owners];
    one-sided), where `checked.clause` holds for the row (its owner's layer is near; other rows
    are cleared vertically): 2 if it clears every such region by more than `rules.disk_separation`
    (`contingency_clearance` with the fans inflated by `rules.reach`); else 1 if, against every
    region it does not clear, it keeps at least as far as the trajectory in force `reference` over
    the same steps (a start layout closer than the clause: pairs only move apart); else 0. Also
    the smallest clearance of a pair it does not clear (infinite if none; with 0, the clearance
    from a region it keeps less far from than the reference).
    Between calls with the same reference (`first_allowed`'s candidates), `known` (an entry per row
    of `others`, then per `lone` centre; NaN until computed) keeps the reference's clearances, and
    hint[0] the entry that failed last (-1: none), which is tried first: the answer is 0 as soon as
    any entry fails, whichever it is. Rows of `others` marked in `far` clear their regions for
    certain (`bounds.clause_out_of_reach`) and are skipped."""
    n = checked.others.shape[0]
    if hint[0] >= 0 and not (hint[0] < n and far[hint[0]]):
        state, c = _against(hint[0], mine, reference, checked, rules, known)
        if state == 0:
            return 0, c
    code, worst = 2, math.inf
    for o in range(n + checked.lone.shape[0]):
        if o < n and far[o]:
            continue
        state, c = _against(o, mine, reference, checked, rules, known)
        if state == 0:
            hint[0] = o
            return 0, c
        if state == 1:
            code, worst = 1, min(worst, c)
    return code, worst


@njit(cache=True)
def _against(
    o: int, mine: Expanded, reference: Expanded, checked: Checked, rules: Rules, known: FloatArray
) -> tuple[int, float]:
    """`keeps_contingencies` against one region: 2 clears, 1 keeps as far as the reference, 0 not.

    `keeps_contingencies` against its entry o (a row of `others`, then a `lone` centre): 2 it
    clears the region, 1 it does not but keeps as far as the reference (and its clearance), 0 it
    keeps less far."""
    pts, others = mine.pts, checked.others
    reach, disk_separation = rules.reach, rules.disk_separation
    width = pts.shape[0]
    if o < others.shape[0]:
        if not checked.clause[o]:
            return 2, math.inf
        ox, oy, oe = checked.centres[o, 0], checked.centres[o, 1], checked.entries[o]
        count, other_count = fan_count(mine.entry, width), fan_count(oe, width)
        if _clearly_clear(
            pts, count, mine.cx, mine.cy, others[o], other_count, ox, oy, reach + disk_separation
        ):
            return 2, math.inf
        # the pair's clearance, min(mine, theirs) - reach (`contingency_clearance`), is at most mine,
        # which is at most the clearance from the other's loiter centre (`_centre_clearance`): a
        # trajectory closer than the reference to the other's region fails without the fans
        near = _centre_clearance(pts, ox, oy) - reach
        if near <= disk_separation and near < _reference_clearance(known, o, reference, checked, reach):
            return 0, near
        clear = fan_clearance(pts, others[o], other_count, ox, oy) - reach
        if clear <= disk_separation and clear < _reference_clearance(known, o, reference, checked, reach):
            return 0, clear
        c = min(clear, fan_clearance(others[o], pts, count, mine.cx, mine.cy) - reach)
        if c > disk_separation:
            return 2, math.inf
        return (0 if c < _reference_clearance(known, o, reference, checked, reach) else 1), c
    lo = o - others.shape[0]
    owner = checked.lone_owners[lo]
    flown = fan_count(checked.entries[owner], width)
    lx, ly = checked.lone[lo, 0], checked.lone[lo, 1]
    if point_clearance(pts, lx, ly) - fan_radius(others[owner], flown, lx, ly) - reach > disk_separation:
        return 2, math.inf
    c = fan_clearance(pts, others[owner], flown, lx, ly) - reach
    if c > disk_separation:
        return 2, math.inf
    if math.isnan(known[o]):
        known[o] = fan_clearance(reference.pts, others[owner], flown, lx, ly) - reach
    return (0 if c < known[o] else 1), c


@njit(cache=True)
def _centre_clearance(a: FloatArray, cx: float, cy: float) -> float:
    """The closest approach of the chords of `a` to (cx, cy), as `fan_clearance` measures it.

    The closest approach of the chords of `a` to (cx, cy), computed as `fan_clearance` does for
    the fan's centre: never below `fan_clearance(a, ..., cx, cy)`, to the last bit."""
    best = math.inf
    for t in range(a.shape[0] - 1):
        best = min(best, to_segment(cx, cy, a[t, 0], a[t, 1], a[t + 1, 0], a[t + 1, 1]))
    return best


@njit(cache=True)
def _reference_clearance(
    known: FloatArray, o: int, reference: Expanded, checked: Checked, reach: float
) -> float:
    """`contingency_clearance` of the reference and others[o], computed once (`keeps_contingencies`)."""
    if math.isnan(known[o]):
        other, ox, oy = checked.others[o], checked.centres[o, 0], checked.centres[o, 1]
        known[o] = contingency_clearance(
            reference.pts,
            reference.entry,
            reference.cx,
            reference.cy,
            other,
            checked.entries[o],
            ox,
            oy,
            reach,
        )
    return known[o]
