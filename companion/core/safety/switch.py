"""The switch rule: whether a pending proposal may replace the trajectory in force."""

from __future__ import annotations

import numpy as np
from numba import njit

from companion.core.geometry import BoolArray, FloatArray, IntArray
from companion.core.safety.contingency import keeps_contingencies
from companion.core.safety.expansion import expand_rows, loiter_centres
from companion.core.safety.failsafe_regions import leaves_loiters
from companion.core.safety.separation import compatible, keeps_apart, split_crowded
from companion.core.trajectory import HEAD


@njit(cache=True)
def may_switch(
    rows: FloatArray,
    first: int,
    window: int,
    kinematics: tuple[float, bool, float, float, float],
    entry: int,
    reference_entry: int,
    others: FloatArray,
    in_force: BoolArray,
    disks: FloatArray,
    tethers: FloatArray,
    tether_disks: FloatArray,
    fans: tuple[FloatArray, FloatArray, IntArray],
    progress: float,
    entries: IntArray,
    centres: FloatArray,
    lone: FloatArray,
    lone_owners: IntArray,
    clause: BoolArray,
    reach: float,
    clearances: tuple[float, float, float],
) -> bool:
    """Whether the proposal rows[0] may replace the trajectory in force rows[1] at step `first`
    (`Commitments.resolve`): both expanded from `first`, with their loiters' entry indices `entry`
    and `reference_entry`, the proposal must be compatible with `others` (their trajectories in
    force `in_force`), the `disks`, `tethers` and `tether_disks`, except that from a trajectory in
    force that is already too close it must only keep apart (`split_crowded`, `keeps_apart`), and
    it must leave the silent UAVs' regions (`leaves_loiters`) and keep the contingency clause
    (`keeps_contingencies`)."""
    horizon = rows.shape[1] - HEAD
    separation, disk_separation, link = clearances
    expanded = expand_rows(rows, first, window, *kinematics)
    starts = np.empty(2, dtype=np.int64)
    for r in range(2):
        starts[r] = int(rows[r, 0]) + horizon - first
    loiter = loiter_centres(expanded, starts)
    pts, inforce = expanded[0], expanded[1]
    normal, crowded, need = split_crowded(inforce, others, in_force, separation)
    if not compatible(pts, normal, disks, tethers, tether_disks, separation, disk_separation, link):
        return False
    if not keeps_apart(pts, crowded, need)[0]:
        return False
    loiters, paths, counts = fans
    if not leaves_loiters(pts, inforce, loiters, paths, counts, disk_separation, horizon, progress):
        return False
    known, hint = np.full(others.shape[0] + lone.shape[0], np.nan), np.full(1, -1)
    code, _ = keeps_contingencies(
        pts,
        entry,
        loiter[0, 0],
        loiter[0, 1],
        inforce,
        reference_entry,
        loiter[1, 0],
        loiter[1, 1],
        others,
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
    return code != 0
