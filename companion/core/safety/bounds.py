"""Bounding circles that prune pairs out of reach before the exact tests (`first_allowed`).

Every candidate's points lie within `Candidates.radius` of the anchor and its loiter centre
within `Candidates.centre_radius`; an other's expanded trajectory lies within the circle about
its first point through its farthest point (a disk is convex: its chords do too). A row whose
circle is further from the candidates' than a test's threshold passes that test for every
candidate: it is marked once a search and never measured. The bounds keep `SLACK` over the
threshold, far above the rounding of either computation (metres, at coordinates below 1e6 m:
about 1e-9 m), so a skipped pair is one the exact test passes to the last bit.
"""

from __future__ import annotations

import math

from numba import njit

from companion.core.geometry import BoolArray, FloatArray
from companion.core.trajectory import segment_clearance

SLACK = 1e-3  # m: a pruned pair clears the threshold by this much at least


@njit(cache=True)
def radius_about_first(pts: FloatArray) -> float:
    """How far the farthest point of `pts` lies from pts[0]: the circle that holds its chords."""
    r = 0.0
    for t in range(1, pts.shape[0]):
        r = max(r, math.hypot(pts[t, 0] - pts[0, 0], pts[t, 1] - pts[0, 1]))
    return r


@njit(cache=True)
def separation_out_of_reach(
    x: float, y: float, radius: float, others: FloatArray, separation: float, far: BoolArray
) -> None:
    """Mark in `far` the rows of `others` every candidate clears by more than `separation`.

    far[o]: `segment_clearance` of any trajectory within `radius` of (x, y) from others[o] is
    above `separation` (two points, each in its disk, are at least the disks' gap apart)."""
    for o in range(others.shape[0]):
        gap = math.hypot(x - others[o, 0, 0], y - others[o, 0, 1]) - radius - radius_about_first(others[o])
        far[o] = gap > separation + SLACK


@njit(cache=True)
def separated_from(pts: FloatArray, others: FloatArray, far: BoolArray, separation: float) -> bool:
    """`compatible`'s test against `others` alone: every `segment_clearance` above `separation`.

    The same answer as `compatible`'s loop over `others`; the rows marked in `far`
    (`separation_out_of_reach`) are not measured."""
    for o in range(others.shape[0]):
        if not far[o] and segment_clearance(pts, others[o]) <= separation:
            return False
    return True


@njit(cache=True)
def clause_out_of_reach(
    x: float,
    y: float,
    radius: float,
    centre_radius: float,
    others: FloatArray,
    centres: FloatArray,
    beyond: float,
    far: BoolArray,
) -> None:
    """Mark in `far` the rows whose fans' disks every candidate surely clears by more than `beyond`.

    far[o]: the contingency clause's cheap test (`contingency._clearly_clear`) passes for every
    trajectory within `radius` of (x, y) whose loiter centre is within `centre_radius` of it,
    against others[o] (its loiter centre centres[o]): a point's distance to chords inside a circle
    is at least its distance to the circle, and a fan's radius about a centre at most the centre's
    distance to the circle's centre plus the circle's radius."""
    for o in range(others.shape[0]):
        bx, by, br = others[o, 0, 0], others[o, 0, 1], radius_about_first(others[o])
        ox, oy = centres[o, 0], centres[o, 1]
        mine = math.hypot(ox - x, oy - y) - radius - math.hypot(ox - bx, oy - by) - br
        theirs = math.hypot(x - bx, y - by) - br - radius - 2 * centre_radius
        far[o] = min(mine, theirs) > beyond + SLACK
