"""The safety kernels' bundled arguments: one UAV's constants, a step's checked rows, its regions.

NamedTuples of arrays and numbers, so that the compiled checks (`switch`, `proposal`,
`contingency`, `gathered`) take a few arguments each and numba compiles and caches them
like any tuple.
"""

from __future__ import annotations

from typing import NamedTuple

from companion.core.geometry import BoolArray, FloatArray, IntArray

KinematicsArgs = tuple[float, bool, float, float, float]  # loiter turn, grid, speed, dt, cell (eq. 2)
# Python hands the compiled entry points (`gathered`) the fields of `Rules`, `Regions` and
# `Candidates` as plain tuples, which numba types in C (a NamedTuple costs about a microsecond a
# call); the entry points name them, `Rules(*rules)`.
FenceArgs = tuple[FloatArray, FloatArray, FloatArray, FloatArray]  # half-planes, keep-outs
RulesArgs = tuple[int, int, KinematicsArgs, *FenceArgs, float, float, float, float, float]
RegionsArgs = tuple[FloatArray, FloatArray, IntArray]
CandidatesArgs = tuple[IntArray, FloatArray, FloatArray, float, float, float, float, FloatArray, float, float]


class Rules(NamedTuple):
    """The constants of one UAV's safety checks.

    The constants of one UAV's checks: the `window` compared and the plan's `horizon` (M), the
    kinematics of eq. 2 (`Limits.kinematics_args`), the fence's half-planes and keep-out
    triangles of paths and of fans' spokes (`search_area.keepout_pieces`), the clearances of
    `Limits` (separation, disk separation, link), the contingency clause's fan `reach` (-inf: the
    clause is off) and the `progress` per planned step of a UAV leaving a failsafe region."""

    window: int
    horizon: int
    kinematics: KinematicsArgs
    normals: FloatArray
    offsets: FloatArray
    keepout: FloatArray
    fan_keepout: FloatArray
    separation: float
    disk_separation: float
    link: float
    reach: float
    progress: float


class Regions(NamedTuple):
    """Where gone UAVs' aircraft fly: disks and the fans of their paths.

    Where gone UAVs' aircraft fly (`failsafe_regions.clears_loiters`): disks (cx, cy, r), the
    fans' paths (n, M + 1, 2) and how many points of each path the fan takes."""

    loiters: FloatArray
    paths: FloatArray
    counts: IntArray


class Checked(NamedTuple):
    """What a check holds a trajectory against, selected from a step's gathering.

    What a check holds a trajectory against (`gathered.select_checked`): the others'
    expanded trajectories, which are `in_force` (else proposals), their loiter `centres` and entry
    indices, the disks (cx, cy, r) of UAVs not heard, the tethers and the tethers' disks, the
    `lone` loiter centres of trajectories in force announced before the latest and the rows of
    their owners, and whether the contingency clause holds against each row."""

    others: FloatArray
    in_force: BoolArray
    centres: FloatArray
    entries: IntArray
    disks: FloatArray
    tethers: FloatArray
    tether_disks: FloatArray
    lone: FloatArray
    lone_owners: IntArray
    clause: BoolArray


class Expanded(NamedTuple):
    """A trajectory over the window: its positions, its loiter's entry index and centre (cx, cy)."""

    pts: FloatArray
    entry: int
    cx: float
    cy: float


class Candidates(NamedTuple):
    """The candidate paths of a new proposal (eq. 23), placed at the UAV's pose.

    The candidate paths of a new proposal (`proposal.first_allowed`): their `order` of
    preference, their `shapes` (n_paths, 2 sides, window + 1, 2) and loiter `centres` (n_paths,
    2 sides, 2) relative to the anchor (`Limits.shapes`), placed at (x, y) and turned by the
    heading (cos_h, sin_h), the point their loiters turn `towards`, and how far from (x, y) any
    of their points (`radius`) and loiter centres (`centre_radius`) lies (`bounds`)."""

    order: IntArray
    shapes: FloatArray
    centres: FloatArray
    x: float
    y: float
    cos_h: float
    sin_h: float
    towards: FloatArray
    radius: float
    centre_radius: float
