"""The switch rule: whether a pending proposal may replace the trajectory in force."""

from __future__ import annotations

import numpy as np
from numba import njit

from companion.core.geometry import FloatArray
from companion.core.safety.contingency import keeps_contingencies
from companion.core.safety.expansion import expand_rows, loiter_centres
from companion.core.safety.failsafe_regions import leaves_loiters
from companion.core.safety.inputs import Checked, Expanded, Regions, Rules
from companion.core.safety.separation import compatible, keeps_apart, split_crowded


@njit(cache=True)
def may_switch(
    rows: FloatArray,
    first: int,
    entry: int,
    reference_entry: int,
    checked: Checked,
    regions: Regions,
    rules: Rules,
) -> bool:
    """The switch rule: whether the proposal rows[0] may replace the trajectory in force rows[1].

    Whether the proposal rows[0] may replace the trajectory in force rows[1] at step `first`
    (`Commitments.resolve`): both expanded from `first`, with their loiters' entry indices `entry`
    and `reference_entry`, the proposal must be compatible with everything `checked` (the others,
    the disks, the tethers and their disks), except that from a trajectory in force that is
    already too close it must only keep apart (`split_crowded`, `keeps_apart`), and it must leave
    the silent UAVs' `regions` (`leaves_loiters`) and keep the contingency clause
    (`keeps_contingencies`)."""
    horizon = rules.horizon
    expanded = expand_rows(rows, first, rules.window, *rules.kinematics)
    starts = np.empty(2, dtype=np.int64)
    for r in range(2):
        starts[r] = int(rows[r, 0]) + horizon - first
    loiter = loiter_centres(expanded, starts)
    pts, inforce = expanded[0], expanded[1]
    normal, crowded, need = split_crowded(inforce, checked.others, checked.in_force, rules.separation)
    if not compatible(
        pts,
        normal,
        checked.disks,
        checked.tethers,
        checked.tether_disks,
        rules.separation,
        rules.disk_separation,
        rules.link,
    ):
        return False
    if not keeps_apart(pts, crowded, need)[0]:
        return False
    loiters, paths, counts = regions
    if not leaves_loiters(
        pts, inforce, loiters, paths, counts, rules.disk_separation, horizon, rules.progress
    ):
        return False
    known, hint = np.full(checked.others.shape[0] + checked.lone.shape[0], np.nan), np.full(1, -1)
    mine = Expanded(pts, entry, loiter[0, 0], loiter[0, 1])
    reference = Expanded(inforce, reference_entry, loiter[1, 0], loiter[1, 1])
    far = np.zeros(checked.others.shape[0], dtype=np.bool_)  # no row skipped
    code, _ = keeps_contingencies(mine, reference, checked, rules, known, hint, far)
    return code != 0
