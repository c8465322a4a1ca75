"""What a UAV gathered this step of the others' commitments, and the compiled checks that read it.

`Commitments._gather` expands, once a step, everything the other UAVs may fly (`Gathered`); each
check selects its rows from it inside the compiled call (`select_checked`), so that the arrays
never cross back into Python: resolving a proposal (`may_switch_from`), keeping the trajectory in
force flyable (`flyable_from`) and searching a new proposal (`first_allowed_from`).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from companion.core.geometry import BoolArray, FloatArray, IntArray
from companion.core.safety.expansion import expand_with_centres
from companion.core.safety.inputs import (
    Candidates,
    CandidatesArgs,
    Checked,
    Expanded,
    KinematicsArgs,
    Regions,
    RegionsArgs,
    Rules,
    RulesArgs,
)
from companion.core.safety.proposal import first_allowed
from companion.core.safety.separation import flyable
from companion.core.safety.switch import may_switch

# What the others may fly, expanded from t_k, a row each (`Commitments._gather`): the table it
# was expanded from (per row a kernel row, then its owner, 1 if a trajectory in force (else a
# proposal), its loiter entry step and 1 if the contingency clause holds against it (its owner's
# layer is near); after the first `count` rows, those of the trajectories in force before their
# owners' latest that are lone, then the row of that owner's latest), `count`, the step t_k, the
# positions (count, window + 2, 2) and loiter centres of the rows, the lone trajectories' loiter
# centres, and the disks (cx, cy, r) of UAVs not heard and their owners. A plain tuple, as
# `safety.inputs.RulesArgs`. The positions and centres are buffers kept from step to step
# (`gathered_rows` fills them: a kernel that returns arrays costs microseconds to box them): only
# their leading rows, as many as the table's, are this step's.
Gathered = tuple[FloatArray, int, int, FloatArray, FloatArray, FloatArray, FloatArray, IntArray]
EXTRA = 4  # columns of `Gathered`'s table after a kernel row


@njit(cache=True)
def gathered_rows(
    table: FloatArray,
    count: int,
    first: int,
    window: int,
    kinematics: KinematicsArgs,
    pts: FloatArray,
    centres: FloatArray,
    lone: FloatArray,
) -> None:
    """Write the positions and loiter centres of a step's gathering and its lone loiter centres.

    From the table of `Gathered`, into the leading rows of the buffers `pts`, `centres` and
    `lone`: the first `count` rows expanded from step `first` over window + 1 steps and their
    loiter centres, and the loiter centres of the rest (over window)."""
    width = table.shape[1] - EXTRA
    rows = np.ascontiguousarray(table[:count, :width])
    expanded, rows_centres = expand_with_centres(rows, first, window + 1, kinematics)
    pts[:count] = expanded
    centres[:count] = rows_centres
    rest = np.ascontiguousarray(table[count:, :width])
    lone[: rest.shape[0]] = expand_with_centres(rest, first, window, kinematics)[1]


@njit(cache=True)
def _columns(
    table: FloatArray, count: int, first: int
) -> tuple[IntArray, BoolArray, IntArray, BoolArray, IntArray]:
    """The owners, in force, loiter entry indices from `first`, clause and lone rows of the table."""
    width = table.shape[1] - EXTRA
    owners = np.empty(count, dtype=np.int64)
    in_force = np.empty(count, dtype=np.bool_)
    entries = np.empty(count, dtype=np.int64)
    clause = np.empty(count, dtype=np.bool_)
    for i in range(count):
        owners[i] = int(table[i, width])
        in_force[i] = table[i, width + 1] != 0.0
        entries[i] = int(table[i, width + 2]) - first
        clause[i] = table[i, width + 3] != 0.0
    lone_rows = np.empty(table.shape[0] - count, dtype=np.int64)
    for o in range(lone_rows.shape[0]):
        lone_rows[o] = int(table[count + o, width])
    return owners, in_force, entries, clause, lone_rows


@njit(cache=True)
def select_checked(
    gathered: Gathered, links: IntArray, uav: int, resolving: bool, proposals: bool
) -> Checked:
    """The rows of this step's gathering a check holds a trajectory against (`Checked`).

    What a check reads from this step's gathering and the tethered UAVs `links` (sorted): the
    rows checked, the disks, the tethers and their disks, the `lone` centres and their owners'
    rows (`Checked`). Rows checked: trajectories in force, and the others' proposals unless not
    `proposals`, or when `resolving` only those of lower ids than `uav`; their window from t_k
    when `resolving`, else from t_k+1. Contiguous copies: the kernels are compiled for C-ordered
    arrays."""
    table, count, first, pts, centres, lone_buffer, disks, disk_owners = gathered
    owners, in_force, entries, clause, lone_rows = _columns(table, count, first)
    n, width = count, pts.shape[1] - 1
    lo = 0 if resolving else 1
    keep = np.empty(n, dtype=np.bool_)
    for i in range(n):
        keep[i] = in_force[i] or (proposals and not (resolving and owners[i] > uav))
    rows = np.flatnonzero(keep)
    linked = np.empty(n, dtype=np.bool_)
    for i in range(n):
        linked[i] = keep[i] and _member(owners[i], links)
    tethered = np.flatnonzero(linked)
    others = np.empty((rows.shape[0], width, 2))
    for r in range(rows.shape[0]):
        others[r] = pts[rows[r], lo : lo + width]
    tethers = np.empty((tethered.shape[0], width, 2))
    for r in range(tethered.shape[0]):
        tethers[r] = pts[tethered[r], lo : lo + width]
    tether_disks = np.empty((0, 3))
    for d in range(disks.shape[0]):
        if _member(disk_owners[d], links):
            tether_disks = np.concatenate((tether_disks, disks[d : d + 1]))
    position = np.full(n, -1, dtype=np.int64)
    for r in range(rows.shape[0]):
        position[rows[r]] = r
    lone_owners = np.empty(lone_rows.shape[0], dtype=np.int64)
    for o in range(lone_rows.shape[0]):
        lone_owners[o] = position[lone_rows[o]]
    return Checked(
        others,
        in_force[rows],
        centres[rows],
        entries[rows] - lo,
        disks,
        tethers,
        tether_disks,
        np.ascontiguousarray(lone_buffer[: lone_rows.shape[0]]),
        lone_owners,
        clause[rows],
    )


@njit(cache=True)
def _member(value: int, sorted_values: IntArray) -> bool:
    """Whether `value` is in the ascending array `sorted_values`."""
    i = np.searchsorted(sorted_values, value)
    return i < sorted_values.shape[0] and sorted_values[i] == value


@njit(cache=True)
def may_switch_from(
    gathered: Gathered,
    links: IntArray,
    uav: int,
    rows: FloatArray,
    first: int,
    entry: int,
    reference_entry: int,
    regions: RegionsArgs,
    rules: RulesArgs,
) -> bool:
    """`may_switch` against this step's gathering (resolving the pending proposal).

    `safety.switch.may_switch` of the proposal rows[0] against what this step's gathering holds
    (`select_checked` for the resolution: the others' proposals only of lower ids, from t_k)."""
    checked = select_checked(gathered, links, uav, True, True)
    return may_switch(rows, first, entry, reference_entry, checked, Regions(*regions), Rules(*rules))


@njit(cache=True)
def flyable_from(
    gathered: Gathered, links: IntArray, uav: int, row: FloatArray, first: int, rules: RulesArgs
) -> bool:
    """`flyable` against the others' trajectories in force and the tethers, from t_k.

    `safety.separation.flyable` against the others' trajectories in force of this step's
    gathering and the tethers among them, from t_k (`Commitments._flyable`)."""
    checked = select_checked(gathered, links, uav, True, False)
    return flyable(row, first, Rules(*rules), checked.others, checked.tethers)


@njit(cache=True)
def first_allowed_from(
    gathered: Gathered,
    links: IntArray,
    uav: int,
    first: int,
    reference_row: FloatArray,
    reference_entry: int,
    candidates: CandidatesArgs,
    regions: RegionsArgs,
    rules: RulesArgs,
) -> tuple[int, int]:
    """`first_allowed` against this step's gathering, from t_k+1.

    `safety.proposal.first_allowed` against everything this step's gathering holds, from t_k+1
    = `first` (`select_checked` for a new proposal), with the trajectory in force `reference_row`
    expanded from there (loiter entry index `reference_entry`) as the reference."""
    checked = select_checked(gathered, links, uav, False, True)
    named = Rules(*rules)
    reference, centre = expand_with_centres(reference_row, first, named.window, named.kinematics)
    reference_trajectory = Expanded(reference[0], reference_entry, centre[0, 0], centre[0, 1])
    return first_allowed(Candidates(*candidates), reference_trajectory, checked, Regions(*regions), named)
