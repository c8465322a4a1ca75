"""Compatibility of trajectories: separation between chords, tethers within range, the fence."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from companion.core.geometry import BoolArray, FloatArray
from companion.core.safety.inputs import Rules
from companion.core.search_area import clear_of
from companion.core.trajectory import expand, point_clearance, segment_clearance


@njit(cache=True)
def inside_fence(pts: FloatArray, normals: FloatArray, offsets: FloatArray, keepout: FloatArray) -> bool:
    """Every point within the fence's half-planes, and no point or chord in the keep-out.

    Chords between points inside stay inside (the fence is convex); the keep-out (the region's
    notches and the inflated no-fly zones, `search_area.keepout_pieces`) is checked chord by chord."""
    for t in range(pts.shape[0]):
        for e in range(normals.shape[0]):
            if pts[t, 0] * normals[e, 0] + pts[t, 1] * normals[e, 1] > offsets[e]:
                return False
    return clear_of(pts, keepout)


@njit(cache=True)
def compatible(
    pts: FloatArray,
    others: FloatArray,
    disks: FloatArray,
    tethers: FloatArray,
    tether_disks: FloatArray,
    separation: float,
    disk_separation: float,
    link: float,
) -> bool:
    """Whether a trajectory keeps its separation from others and disks and its tethers' links.

    Whether the trajectory at `pts` (window + 1 positions) keeps clear of every expanded
    trajectory in `others` and every disk (cx, cy, r) in `disks` between sampling moments, and
    within `link` of every trajectory in `tethers` and of all of every disk in `tether_disks` at
    every sampling moment."""
    for o in range(others.shape[0]):
        if segment_clearance(pts, others[o]) <= separation:
            return False
    for d in range(disks.shape[0]):
        if point_clearance(pts, disks[d, 0], disks[d, 1]) - disks[d, 2] <= disk_separation:
            return False
    for o in range(tethers.shape[0]):
        for t in range(pts.shape[0]):
            if math.hypot(pts[t, 0] - tethers[o, t, 0], pts[t, 1] - tethers[o, t, 1]) >= link:
                return False
    for d in range(tether_disks.shape[0]):
        for t in range(pts.shape[0]):
            far = (
                math.hypot(pts[t, 0] - tether_disks[d, 0], pts[t, 1] - tether_disks[d, 1])
                + tether_disks[d, 2]
            )
            if far >= link:
                return False
    return True


@njit(cache=True)
def clearances(pts: FloatArray, others: FloatArray) -> FloatArray:
    """`segment_clearance` of the trajectory at `pts` from each of `others`."""
    out = np.empty(others.shape[0])
    for o in range(others.shape[0]):
        out[o] = segment_clearance(pts, others[o])
    return out


@njit(cache=True)
def keeps_apart(pts: FloatArray, crowded: FloatArray, need: FloatArray) -> tuple[bool, float]:
    """Recovery: whether a trajectory keeps a crowded pair's clearance from shrinking.

    Recovery for pairs already closer than the separation (after a fault: a partition, a vehicle
    that strayed): whether the trajectory at `pts` keeps at least `need[o]` (the trajectory in force's
    clearance) from each of `crowded`, so the pair's clearance never shrinks, and how far it keeps
    from them after its first point (fixed by the trajectory in force: the next plan starts there)."""
    worst = math.inf
    for o in range(crowded.shape[0]):
        if segment_clearance(pts, crowded[o]) < need[o]:
            return False, -math.inf
        worst = min(worst, segment_clearance(pts[1:], crowded[o, 1:]))
    return True, worst


@njit(cache=True)
def split_crowded(
    reference: FloatArray, others: FloatArray, in_force: BoolArray, separation: float
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The others split by whether the trajectory in force is compatible with them.

    `others` split by whether the trajectory in force (at `reference`, the same steps) is
    compatible with them: those it is, and the others' trajectories in force (`in_force`) it is
    already too close to (after a fault), with its clearance from each (`keeps_apart`). A proposal
    it is too close to stays a strict obstacle: its owner will not switch to it."""
    gaps = clearances(reference, others)
    close = (gaps <= separation) & in_force
    return others[~close], others[close], gaps[close]


@njit(cache=True)
def flyable(row: FloatArray, first: int, rules: Rules, others: FloatArray, tethers: FloatArray) -> bool:
    """Whether a trajectory stays in the fence and is compatible with `others` and `tethers`.

    Whether the trajectory `row`, expanded from step `first` over `rules.window`, stays in the
    fence and is compatible with the trajectories `others` and `tethers` (`Commitments._flyable`)."""
    pts = expand(row, first, rules.window, *rules.kinematics)
    if not inside_fence(pts, rules.normals, rules.offsets, rules.keepout):
        return False
    no_disks = np.zeros((0, 3))
    return compatible(
        pts, others, no_disks, tethers, no_disks, rules.separation, rules.disk_separation, rules.link
    )
