"""The safety layer's geometry: when two committed trajectories are compatible, which candidate
paths may be proposed, and the contingencies every UAV starts with.

Two trajectories are *compatible* when, for every time from the first step compared on (between
sampling moments too), the UAVs flying them are farther apart than `Limits.separation`, and, for
a tether (a link that must hold), closer than `Limits.link` at every sampling moment. Trajectories
end in loiters, so comparing `Reach.window` steps covers all later time. Positions between
sampling moments are compared along the chords, with the arcs' sagitta added to the distances
(`trajectory.arc_chord_deviation`). The fence is the search region with each edge pushed out by
the mission's `safety.margin` (the operating margin): every trajectory stays inside it forever.

The protocol that keeps every pair of in-force trajectories compatible is in `commitment.py`; the
invariant and its argument are in docs/algorithm.md ("Safety layer").
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np
from numba import njit

from companion.core.geometry import BoolArray, ConvexPolygon, FloatArray, IntArray
from companion.core.kinematics import Kinematics
from companion.core.trajectory import HEAD, Reach, Trajectory, expand, point_clearance, segment_clearance

TURN_SIDES = (1, -1)


@dataclass(frozen=True)
class Limits:
    """What compatibility means for one mission.

    `separation`: the clearance two trajectories' chords must keep (R_s + buffer + both sagittas);
    `disk_separation`: the clearance a chord keeps from a disk (R_s + buffer + one sagitta);
    `link`: the largest tether length at a sampling moment (R_c - buffer);
    `fence_normals`, `fence_offsets`: the fence's half-planes, pulled in by the sagitta.
    """

    reach: Reach
    horizon: int
    grid: bool
    speed: float
    dt: float
    cell: float
    separation: float
    disk_separation: float
    link: float
    fence_normals: FloatArray
    fence_offsets: FloatArray

    @classmethod
    def build(
        cls,
        kin: Kinematics,
        horizon: int,
        region: ConvexPolygon,
        r_s: float,
        r_c: float,
        margin: float,
        buffer: float,
    ) -> Limits:
        reach = Reach.of(kin, horizon)
        sag = reach.sagitta
        return cls(
            reach,
            horizon,
            kin.mode == "grid",
            kin.speed,
            kin.dt,
            kin.cell_size,
            r_s + buffer + 2 * sag,
            r_s + buffer + sag,
            r_c - buffer,
            np.ascontiguousarray(region.normals),
            region.offsets + margin - sag,
        )

    def expand(self, rows: FloatArray, first: int) -> FloatArray:
        """Positions of every trajectory row at steps first..first + window: (n, window + 1, 2)."""
        r = self.reach
        return expand_rows(rows, first, r.window, r.loiter_turn, self.grid, self.speed, self.dt, self.cell)

    def shapes(self, sequences: FloatArray) -> FloatArray:
        """Every candidate trajectory relative to its anchor, for each loiter side (+1, -1):
        (headings, n_paths, 2, window + 1, 2). Grid mode keeps one table per 45-degree heading;
        continuous mode one for heading 0, which `feasible_sides` turns (eq. 2 turns with the
        heading it starts from)."""
        r = self.reach
        headings = np.arange(8) * math.pi / 4 if self.grid else np.zeros(1)
        out = np.empty((len(headings), len(sequences), 2, r.window + 1, 2))
        row = np.empty(HEAD + self.horizon)
        for h, heading in enumerate(headings):
            for i, seq in enumerate(sequences):
                for s, side in enumerate(TURN_SIDES):
                    row[:HEAD] = (0, 0.0, 0.0, heading, side)
                    row[HEAD:] = seq
                    out[h, i, s] = expand(row, 0, r.window, *self.kinematics_args)
        return out

    def rows(self, trajectories: list[Trajectory]) -> FloatArray:
        """The kernel rows of `trajectories` (`Trajectory.fields`)."""
        flat: list[float] = []
        for t in trajectories:
            flat += t.fields(self.horizon)
        return np.array(flat, dtype=float).reshape(-1, HEAD + self.horizon)

    def planned_path(self, trajectory: Trajectory) -> FloatArray:
        """Its positions from its anchor to the end of its M planned steps: (horizon + 1, 2)."""
        return self.expand(self.rows([trajectory]), trajectory.start)[0, : self.horizon + 1]

    def loiter_circle(self, trajectory: Trajectory) -> tuple[float, float, float]:
        """The circle (centre x, centre y, radius) of `trajectory`'s loiter: through its sampling points
        in continuous mode; in grid mode the loiter octagon's circumscribed circle (its vertices are
        concyclic: equal angles, alternating sides). The centre is the circumcentre of three
        consecutive loiter points, the radius the farthest of a whole loop's points from it."""
        r = self.reach
        row = self.rows([trajectory])[0]
        pts = expand(row, trajectory.start + self.horizon, r.period, *self.kinematics_args)
        ux, uy = loiter_centre(pts, 0)
        return ux, uy, float(np.max(np.hypot(pts[:, 0] - ux, pts[:, 1] - uy)))

    def shape_centres(self, shapes: FloatArray) -> FloatArray:
        """The loiter centre of every candidate of `shapes` (`Limits.shapes`) relative to its anchor:
        (headings, n_paths, 2 sides, 2)."""
        out = np.empty((*shapes.shape[:3], 2))
        for index in np.ndindex(*shapes.shape[:3]):
            out[index] = loiter_centre(shapes[index], self.horizon)
        return out

    @property
    def kinematics_args(self) -> tuple[float, bool, float, float, float]:
        return self.reach.loiter_turn, self.grid, self.speed, self.dt, self.cell

    @property
    def clearances(self) -> tuple[float, float, float]:
        """(separation, disk_separation, link), the trailing arguments of `compatible`."""
        return self.separation, self.disk_separation, self.link


@njit(cache=True)
def loiter_centre(pts: FloatArray, first: int) -> tuple[float, float]:
    """The centre of the loiter whose sampling points are pts[first:] (at least three of them, all
    of them if `first` < 0): the circumcentre of three consecutive ones (grid mode's loiter octagon
    has concyclic vertices)."""
    i = min(max(first, 0), pts.shape[0] - 3)
    ax, ay, bx, by, cx, cy = pts[i, 0], pts[i, 1], pts[i + 1, 0], pts[i + 1, 1], pts[i + 2, 0], pts[i + 2, 1]
    d = 2 * (ax * (by - cy) + bx * (cy - ay) + cx * (ay - by))
    a2, b2, c2 = ax * ax + ay * ay, bx * bx + by * by, cx * cx + cy * cy
    ux = (a2 * (by - cy) + b2 * (cy - ay) + c2 * (ay - by)) / d
    uy = (a2 * (cx - bx) + b2 * (ax - cx) + c2 * (bx - ax)) / d
    return ux, uy


@njit(cache=True)
def loiter_centres(pts: FloatArray, firsts: IntArray) -> FloatArray:
    """`loiter_centre` of every expanded trajectory pts[r] from its index firsts[r]: (n, 2)."""
    out = np.empty((pts.shape[0], 2))
    for r in range(pts.shape[0]):
        out[r, 0], out[r, 1] = loiter_centre(pts[r], firsts[r])
    return out


@njit(cache=True)
def expand_rows(
    rows: FloatArray,
    first: int,
    count: int,
    loiter_turn: float,
    grid: bool,
    speed: float,
    dt: float,
    cell: float,
) -> FloatArray:
    """`trajectory.expand` for every row."""
    out = np.empty((rows.shape[0], count + 1, 2))
    for i in range(rows.shape[0]):
        out[i] = expand(rows[i], first, count, loiter_turn, grid, speed, dt, cell)
    return out


@njit(cache=True)
def expand_with_centres(
    rows: FloatArray, first: int, count: int, kinematics: tuple[float, bool, float, float, float]
) -> tuple[FloatArray, FloatArray]:
    """`expand_rows` from step `first` (count + 1 points) and the loiter centres of the rows
    (`loiter_centre`: the loiter begins after a row's M planned turns, at index start + M - first)."""
    pts = expand_rows(rows, first, count, *kinematics)
    horizon = rows.shape[1] - HEAD
    starts = np.empty(rows.shape[0], dtype=np.int64)
    for r in range(rows.shape[0]):
        starts[r] = int(rows[r, 0]) + horizon - first
    return pts, loiter_centres(pts, starts)


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
    """Whether the trajectory at `pts` (window + 1 positions) keeps clear of every expanded
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
    """Recovery for pairs already closer than the separation (after a fault: a partition, a vehicle
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
    """`others` split by whether the trajectory in force (at `reference`, the same steps) is
    compatible with them: those it is, and the others' trajectories in force (`in_force`) it is
    already too close to (after a fault), with its clearance from each (`keeps_apart`). A proposal
    it is too close to stays a strict obstacle: its owner will not switch to it."""
    gaps = clearances(reference, others)
    close = (gaps <= separation) & in_force
    return others[~close], others[close], gaps[close]


@njit(cache=True)
def flyable(
    row: FloatArray,
    first: int,
    window: int,
    kinematics: tuple[float, bool, float, float, float],
    normals: FloatArray,
    offsets: FloatArray,
    others: FloatArray,
    tethers: FloatArray,
    clearances: tuple[float, float, float],
) -> bool:
    """Whether the trajectory `row`, expanded from step `first`, stays in the fence and is
    compatible with the trajectories `others` and `tethers` (`Commitments._flyable`)."""
    pts = expand(row, first, window, *kinematics)
    if not inside_fence(pts, normals, offsets):
        return False
    no_disks = np.zeros((0, 3))
    return compatible(pts, others, no_disks, tethers, no_disks, *clearances)


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


@njit(cache=True)
def clears_loiters(
    pts: FloatArray,
    loiters: FloatArray,
    paths: FloatArray,
    counts: IntArray,
    disk_separation: float,
    horizon: int,
    progress: float,
) -> bool:
    """Whether the trajectory at `pts` (window + 1 positions, its M = `horizon` planned steps first)
    keeps clear of every region where a silent UAV's aircraft flies (`Commitments`): the fan of
    paths[d][:counts[d]] about (cx, cy) of loiters[d] = (cx, cy, r), inflated by r (a disk where
    counts[d] is 0): either it is out of the region, farther than `disk_separation` from it, from
    some step on and for good (its loiter repeats within the window), or it starts within that
    distance and every planned step takes it at least `progress` farther from the fan (a UAV deep
    inside cannot get out within one plan: it gets out plan by plan)."""
    for d in range(loiters.shape[0]):
        cx, cy, r = loiters[d, 0], loiters[d, 1], loiters[d, 2]
        path, count = paths[d], counts[d]
        out = -1
        for t in range(pts.shape[0]):
            if fan_clearance(pts[t : t + 1], path, count, cx, cy) - r > disk_separation:
                out = t
                break
        if out >= 0 and fan_clearance(pts[out:], path, count, cx, cy) - r > disk_separation:
            continue
        if out == 0:
            return False
        for t in range(horizon):
            before = fan_clearance(pts[t : t + 1], path, count, cx, cy)
            if fan_clearance(pts[t + 1 : t + 2], path, count, cx, cy) < before + progress:
                return False
    return True


@njit(cache=True)
def loiter_clearance(pts: FloatArray, loiters: FloatArray, paths: FloatArray, counts: IntArray) -> float:
    """The trajectory's closest approach over the window to the nearest of the regions of
    `clears_loiters`: negative inside one, infinite without any."""
    best = math.inf
    for d in range(loiters.shape[0]):
        cx, cy = loiters[d, 0], loiters[d, 1]
        best = min(best, fan_clearance(pts, paths[d], counts[d], cx, cy) - loiters[d, 2])
    return best


@njit(cache=True)
def leaves_loiters(
    pts: FloatArray,
    reference: FloatArray,
    loiters: FloatArray,
    paths: FloatArray,
    counts: IntArray,
    disk_separation: float,
    horizon: int,
    progress: float,
) -> bool:
    """Whether the trajectory at `pts` may replace the one in force at `reference` (the same steps)
    near the regions of `clears_loiters`: for each, it clears it, or its closest approach to the
    region's fan over the window is larger than the reference's. Where nothing that clears them
    all is flyable (a UAV boxed in by the fence and its neighbours), flying it keeps the UAV
    farther from each silent UAV's aircraft than flying on would, and the next plan starts from
    there."""
    for d in range(loiters.shape[0]):
        one = loiters[d : d + 1]
        if clears_loiters(pts, one, paths[d : d + 1], counts[d : d + 1], disk_separation, horizon, progress):
            continue
        cx, cy, path, count = loiters[d, 0], loiters[d, 1], paths[d], counts[d]
        if fan_clearance(pts, path, count, cx, cy) <= fan_clearance(reference, path, count, cx, cy):
            return False
    return True


@njit(cache=True)
def _to_segment(px: float, py: float, ax: float, ay: float, bx: float, by: float) -> float:
    """The distance from (px, py) to the segment from (ax, ay) to (bx, by)."""
    dx, dy = bx - ax, by - ay
    dd = dx * dx + dy * dy
    s = 0.0 if dd == 0.0 else min(max(((px - ax) * dx + (py - ay) * dy) / dd, 0.0), 1.0)
    return math.hypot(px - ax - s * dx, py - ay - s * dy)


@njit(cache=True)
def _cross(ax: float, ay: float, bx: float, by: float, cx: float, cy: float) -> float:
    return (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)


@njit(cache=True)
def _crosses(ax: float, ay: float, bx: float, by: float, cx: float, cy: float, dx: float, dy: float) -> bool:
    """Whether the segments AB and CD cross (strictly: each one's ends on either side of the other)."""
    d1, d2 = _cross(cx, cy, dx, dy, ax, ay), _cross(cx, cy, dx, dy, bx, by)
    d3, d4 = _cross(ax, ay, bx, by, cx, cy), _cross(ax, ay, bx, by, dx, dy)
    return d1 * d2 < 0 and d3 * d4 < 0


@njit(cache=True)
def _in_fan(px: float, py: float, path: FloatArray, count: int, cx: float, cy: float) -> bool:
    """Whether (px, py) lies in one of the fan's triangles (path[p], path[p + 1], centre)."""
    for p in range(count - 1):
        ax, ay, bx, by = path[p, 0], path[p, 1], path[p + 1, 0], path[p + 1, 1]
        area = _cross(ax, ay, bx, by, cx, cy)
        if area == 0.0:
            continue  # degenerate: its edges are the fan's spokes and path
        d1 = _cross(ax, ay, bx, by, px, py) * area
        d2 = _cross(bx, by, cx, cy, px, py) * area
        d3 = _cross(cx, cy, ax, ay, px, py) * area
        if d1 >= 0 and d2 >= 0 and d3 >= 0:
            return True
    return False


@njit(cache=True)
def fan_clearance(a: FloatArray, path: FloatArray, count: int, cx: float, cy: float) -> float:
    """The closest approach of the polyline `a` (its chords between sampling moments; a point if
    it has one) to the *fan* of path[:count] about the centre (cx, cy): the union of the triangles
    (path[p], path[p + 1], centre), the spokes path[p] -> centre and the centre itself. A silent
    UAV's aircraft, from wherever on its path its failsafe fires, flies towards that centre (its
    committed loiter's): inflated by the failsafe's reach, the fan holds all it flies
    (docs/algorithm.md, "The contingency clause")."""
    for t in range(a.shape[0]):
        if _in_fan(a[t, 0], a[t, 1], path, count, cx, cy):
            return 0.0
    best = math.inf
    if a.shape[0] == 1:
        best = math.hypot(a[0, 0] - cx, a[0, 1] - cy)
        for p in range(count):
            best = min(best, _to_segment(a[0, 0], a[0, 1], path[p, 0], path[p, 1], cx, cy))
        return best
    # the distance between two segments is 0 where they cross, else the least of their ends'
    # distances to the other: a chord crossing a spoke or a path edge touches the fan, and every
    # end-to-segment distance is taken once (a point ends two chords, a path point two edges)
    width = a.shape[0]
    for t in range(width - 1):
        ax, ay, bx, by = a[t, 0], a[t, 1], a[t + 1, 0], a[t + 1, 1]
        for p in range(count):
            qx, qy = path[p, 0], path[p, 1]
            if _crosses(ax, ay, bx, by, qx, qy, cx, cy):
                return 0.0
            if p + 1 < count and _crosses(ax, ay, bx, by, qx, qy, path[p + 1, 0], path[p + 1, 1]):
                return 0.0
    for t in range(width):  # each sampling point to each spoke and path edge
        px, py = a[t, 0], a[t, 1]
        for p in range(count):
            qx, qy = path[p, 0], path[p, 1]
            best = min(best, _to_segment(px, py, qx, qy, cx, cy))
            if p + 1 < count:
                best = min(best, _to_segment(px, py, qx, qy, path[p + 1, 0], path[p + 1, 1]))
    for t in range(width - 1):  # the centre and each path point to each chord
        ax, ay, bx, by = a[t, 0], a[t, 1], a[t + 1, 0], a[t + 1, 1]
        best = min(best, _to_segment(cx, cy, ax, ay, bx, by))
        for p in range(count):
            best = min(best, _to_segment(path[p, 0], path[p, 1], ax, ay, bx, by))
    return best


@njit(cache=True)
def fan_count(entry: int, width: int) -> int:
    """How many points of an expanded trajectory (`width` of them) its fan takes: those up to its
    loiter's entry index `entry`; none once it loiters (its aircraft, holding the loiter turn, then
    stays on the loiter circle: the centre, inflated, covers it)."""
    return 0 if entry <= 0 else min(entry, width - 1) + 1


@njit(cache=True)
def fan_radius(path: FloatArray, count: int, cx: float, cy: float) -> float:
    """The radius about (cx, cy) of the disk that holds the fan of path[:count]."""
    r = 0.0
    for p in range(count):
        r = max(r, math.hypot(path[p, 0] - cx, path[p, 1] - cy))
    return r


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
        best = min(best, _to_segment(cx, cy, a[t, 0], a[t, 1], a[t + 1, 0], a[t + 1, 1]))
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


@njit(cache=True)
def inside_fence(pts: FloatArray, normals: FloatArray, offsets: FloatArray) -> bool:
    """Every point within the fence's half-planes (chords then stay inside: the fence is convex)."""
    for t in range(pts.shape[0]):
        for e in range(normals.shape[0]):
            if pts[t, 0] * normals[e, 0] + pts[t, 1] * normals[e, 1] > offsets[e]:
                return False
    return True


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


# -- the start: a tree of tethers and a contingency for every UAV -------------------------------------


def tether_tree(positions: FloatArray, link: float) -> tuple[tuple[int, ...], tuple[int, ...]]:
    """Ranks and parents of the start layout: ranks in breadth-first order from UAV 0 over the graph
    of pairs closer than `link` (nearer neighbours first), each UAV's parent the nearest UAV of a
    lower rank within `link`, -1 for the root. A layout that is not connected gives a forest: each
    further component is ranked from its lowest id, whose parent is -1 too."""
    n = len(positions)
    d = np.linalg.norm(positions[:, None, :] - positions[None, :, :], axis=-1)
    rank = [-1] * n
    order: list[int] = []
    for root in range(n):
        if rank[root] >= 0:
            continue
        rank[root] = len(order)
        order.append(root)
        queue = deque([root])
        while queue:
            u = queue.popleft()
            for v in sorted(range(n), key=lambda v: d[u, v]):
                if rank[v] < 0 and d[u, v] < link:
                    rank[v] = len(order)
                    order.append(v)
                    queue.append(v)

    def parent(v: int) -> int:
        lower = [u for u in range(n) if rank[u] < rank[v] and d[u, v] < link]
        return min(lower, key=lambda u: d[u, v]) if lower else -1

    return tuple(rank), tuple(parent(v) for v in range(n))


def initial_trajectories(
    poses: FloatArray, parents: tuple[int, ...], ranks: tuple[int, ...], limits: Limits
) -> list[Trajectory]:
    """A contingency per UAV from its start pose, pairwise compatible and keeping every tether to a
    parent: straight for s steps (0 <= s <= M, shorter first), then loiter on one side. Searched in
    rank order with backtracking; raises ValueError when the start layout admits none."""
    n, m = len(poses), limits.horizon
    turn = limits.reach.loiter_turn
    options: list[list[tuple[Trajectory, FloatArray]]] = []
    for x, y, h in poses:
        opts = []
        for s in range(m + 1):
            for side in TURN_SIDES:
                traj = Trajectory(
                    0, float(x), float(y), float(h), (0.0,) * s + (side * turn,) * (m - s), side
                )
                pts = limits.expand(limits.rows([traj]), 0)[0]
                if inside_fence(pts, limits.fence_normals, limits.fence_offsets):
                    opts.append((traj, pts))
        options.append(opts)
    order = sorted(range(n), key=lambda u: ranks[u])
    chosen: dict[int, FloatArray] = {}
    picks: dict[int, Trajectory] = {}
    empty = np.zeros((0, limits.reach.window + 1, 2))
    no_disks = np.zeros((0, 3))

    def place(i: int) -> bool:
        if i == len(order):
            return True
        u = order[i]
        others = np.array([chosen[v] for v in chosen]) if chosen else empty
        tethers = np.array([chosen[parents[u]]]) if parents[u] >= 0 else empty
        for traj, pts in options[u]:
            ok = compatible(
                pts,
                others,
                no_disks,
                tethers,
                no_disks,
                limits.separation,
                limits.disk_separation,
                limits.link,
            )
            if ok:
                chosen[u], picks[u] = pts, traj
                if place(i + 1):
                    return True
                del chosen[u], picks[u]
        return False

    if not place(0):
        raise ValueError(
            "no start contingency: the vehicles cannot all loiter from their start poses inside the "
            "fence while keeping the safety distance and their links"
        )
    return [picks[u] for u in range(n)]


def minimum_margin(kin: Kinematics, horizon: int) -> float:
    """The smallest operating margin with which a UAV anywhere on the region's edge, with any
    heading, has a contingency inside the fence: the largest, over headings, of how far beyond the
    edge its best start contingency (straight for s <= M steps, then loiter) reaches. The edge is a
    straight line through the UAV with outward normal +y."""
    reach = Reach.of(kin, horizon)
    grid = kin.mode == "grid"
    headings = np.arange(8) * math.pi / 4 if grid else np.linspace(-math.pi, math.pi, 361)
    worst = 0.0
    for h in headings:
        best = math.inf
        for s in range(horizon + 1):
            for side in TURN_SIDES:
                row = np.full(HEAD + horizon, float(side) * reach.loiter_turn)
                row[:HEAD] = (0, 0.0, 0.0, h, side)
                row[HEAD : HEAD + s] = 0.0
                pts = expand(row, 0, reach.window, reach.loiter_turn, grid, kin.speed, kin.dt, kin.cell_size)
                best = min(best, float(pts[:, 1].max()))
        worst = max(worst, best)
    return worst + reach.sagitta
