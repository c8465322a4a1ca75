"""One UAV's side of the commitment protocol that keeps the swarm separated and linked.

Every UAV flies a trajectory in force compatible with every other's for all later time; at step k
it publishes it with a proposal, and at k+1 switches to the proposal only if it is compatible
with every neighbour's trajectory in force and, for a lower id, with its proposal too. A UAV not
heard from is represented by everything it could be flying (a growing disk, then, once gone, its
commitments plus its failsafe loiter disks); one not steered is kept clear of like a gone one.
With `safety.contingency`, compatibility also asks each trajectory to keep clear of the other's
failsafe disk, between UAVs on near layers only. Rejecting a proposal is always safe. The
invariant and its argument: docs/algorithm.md, "Safety layer" and "The contingency clause".
"""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np

from companion.core.gathered import (
    EXTRA,
    Gathered,
    first_allowed_from,
    flyable_from,
    gathered_rows,
    may_switch_from,
)
from companion.core.geometry import FloatArray, IntArray
from companion.core.messages import StateMsg, UavState
from companion.core.safety.inputs import CandidatesArgs, RegionsArgs, RulesArgs
from companion.core.safety.separation import compatible
from companion.core.trajectory import HEAD, Trajectory, step_pose
from companion.core.world import FAILSAFE_WIDE, World

Disk = tuple[float, float, float]  # centre x, centre y, radius
ACK_STEPS = 2  # a new parent is taken as tethered once it has heard the UAV name it
LEAVING_PROGRESS = 0.25  # of a step, outwards per planned step, for a UAV inside a failsafe disk
FAR = 1e4  # m: a point this far in a direction stands for the direction
SIDE_RANGE = 600.0  # m: a UAV nearer than this makes a new loiter turn away from it (`_turn_towards`)


class Commitments:
    """UAV `uav`'s trajectories in force and proposed, its tethers, and the others' commitments.

    The trajectories in force and proposed of UAV `uav`, its tethers, and what it knows of the
    others' commitments."""

    def __init__(self, world: World, uav: int) -> None:
        plan = world.safety
        self.world, self.uav, self.limits = world, uav, plan.limits
        self.ranks, self.failsafe = plan.ranks, plan.failsafe_reach
        # how far from its fan a silent UAV's aircraft may fly: holding its last command off its
        # path (`failsafe_stray`), then onto and around its failsafe circle (`failsafe_reach`)
        self.fan_reach = plan.failsafe_reach + plan.failsafe_stray
        # the contingency clause's fan radius (`keeps_contingencies`); -inf: every pair clears it
        self.contingency = self.fan_reach if world.mission.safety.contingency else -math.inf
        # steps after a silent UAV's last message by which its aircraft has flown onto its failsafe
        # circle: the failsafe's delay, a plan's length and a half turn onto the circle, at its speed
        dt, speed = world.mission.kinematics.step, plan.limits.reach.step / world.mission.kinematics.step
        transit = (plan.failsafe_stray + plan.limits.reach.extent + math.pi * plan.loiter_radius) / speed
        self.settle = math.ceil((world.mission.failsafe_seconds + transit) / dt) + 2
        # any circle an autopilot flies through the latest report (at up to FAILSAFE_WIDE loiter
        # radii), entered off its tangent: what a vehicle nobody steers is taken to stay within
        self.adrift_reach = plan.failsafe_reach + FAILSAFE_WIDE * plan.loiter_radius
        self.timeout = world.mission.comms.peer_timeout_steps
        self.near: list[bool] = plan.near[uav].tolist()  # whose failures this UAV guards against
        self.inforce: Trajectory = plan.start[uav]
        self.proposal: Trajectory | None = None  # P_i^{k-1}, resolved at step k
        self.parents: tuple[int, ...] = (plan.parents[uav],) if plan.parents[uav] >= 0 else ()
        self.parent_since = -1  # step the newest parent was named
        self.latest: dict[int, UavState] = {
            j: UavState(j, 0, t.x, t.y, t.heading, (), committed=t)
            for j, t in enumerate(plan.start)
            if j != uav
        }
        self.before: dict[int, Trajectory] = {}  # each UAV's trajectory in force before its latest one
        self.fresh: dict[int, StateMsg] = {}
        self.left: set[int] = set()  # reported gone by the mesh (liveliness), until heard again
        self.dead: set[int] = set()
        self.accepted = self.rejected = self.recovered = 0
        self.first_asked = self.first_refused = 0  # the RHC's first choices, and those refused
        # this step's gathering (`_gather`): what the others may fly, expanded from t_k, a row each
        # (`Gathered`), and the loiter centres of live UAVs' trajectories in force before their latest
        # (into buffers with a row for each trajectory an other may have, `gathered_rows`)
        no_rows = np.zeros((0, HEAD + plan.limits.horizon + EXTRA))
        others = len(plan.start) - 1
        self._buffers = (
            np.zeros((2 * others, plan.limits.reach.window + 2, 2)),  # in force and proposal each
            np.zeros((2 * others, 2)),
            np.zeros((others, 2)),  # a lone trajectory each
        )
        self._no_disks = (np.zeros((0, 3)), np.zeros(0, dtype=np.int64))
        self._gathered: Gathered = (no_rows, 0, 0, *self._buffers, *self._no_disks)
        self._gathered_owners: set[int] = set()  # the UAVs with rows in it
        # where gone UAVs' aircraft fly (`failsafe_regions`): (cx, cy, r), the fans' paths and lengths
        no_paths = np.zeros((0, plan.limits.horizon + 1, 2))
        self._no_regions: RegionsArgs = (np.zeros((0, 3)), no_paths, np.zeros(0, dtype=np.int64))
        self._regions = self._no_regions
        self.progress = LEAVING_PROGRESS * plan.limits.reach.step  # per planned step, leaving a disk
        lim = plan.limits
        self.rules: RulesArgs = (
            lim.reach.window,
            lim.horizon,
            lim.kinematics_args,
            lim.fence_normals,
            lim.fence_offsets,
            lim.keepout,
            lim.fan_keepout,
            lim.separation,
            lim.disk_separation,
            lim.link,
            self.contingency,
            self.progress,
        )
        self._centre = np.asarray(world.grid.region.vertices.mean(axis=0), dtype=float)
        self._kids: set[int] | None = None  # `_children`, until the next `observe` or `gone`
        self._tethers: tuple[int, ...] | None = None  # the parents `_links` holds for, till `observe`
        self._link_ids: list[int] = []
        self._link_array = np.zeros(0, dtype=np.int64)
        # the trajectory in force's kernel row (`_flyable`) and loiter entry step
        self._held: tuple[Trajectory | None, FloatArray, int] = (None, np.zeros((1, 0)), 0)
        self._tables(world)

    def _tables(self, world: World) -> None:
        """The reaches of `_gather`, the start contingencies and the candidates' shapes."""
        lim = self.limits
        r = lim.reach
        # how far another UAV may be to matter (`_gather`): on a near layer, on another, and (plus a
        # disk's radius and the disk separation) a UAV not heard
        self._reaches = (
            2 * r.extent + 2 * r.step + max(lim.separation, self.contingency + lim.disk_separation),
            2 * r.extent + 2 * r.step + lim.separation,
            r.extent + r.step,
        )
        turn, m = r.loiter_turn, lim.horizon
        self._contingencies = [
            ((0.0,) * n + (side * turn,) * (m - n), side) for n in range(m, -1, -1) for side in (1, -1)
        ]
        # their kernel rows but the anchor's step and pose (columns 0-3, `_flyable`)
        self._contingency_rows = np.array(
            [(0, 0, 0, 0, side, *turns) for turns, side in self._contingencies], dtype=float
        )
        self._shapes, self._shape_centres = world.safety.shapes, world.safety.centres
        # per heading, how far any candidate's point and loiter centre lies from its anchor (`bounds`)
        self._radii: list[tuple[float, float]] = [
            (float(np.hypot(p[..., 0], p[..., 1]).max()), float(np.hypot(c[..., 0], c[..., 1]).max()))
            for p, c in zip(self._shapes, self._shape_centres, strict=True)
        ]

    # -- what is known of the others -------------------------------------------------------------
    def observe(self, k: int, fresh: dict[int, StateMsg], states: Iterable[UavState]) -> None:
        """Take this step's first-hand StateMsgs (stamped k - 1) and every state heard or relayed."""
        self.fresh = fresh
        for s in states:
            old = self.latest.get(s.uav)
            if s.uav != self.uav and s.stamp < k and (old is None or s.stamp > old.stamp):
                self.latest[s.uav] = s
                if old is not None and old.committed is not None:
                    self.before[s.uav] = old.committed
        self.left -= fresh.keys()
        self._kids = self._tethers = None
        left, stale = self.left, k - 1 - self.timeout
        self.dead = {
            j
            for j, s in self.latest.items()
            if not s.steered or (j not in fresh and (j in left or s.stamp < stale))
        }

    def gone(self, uav: int) -> None:
        """`uav` has left the mesh (its companion stopped): it flies what it last published."""
        if uav in self.latest:
            self.left.add(uav)
            self.dead.add(uav)
            self._kids = self._tethers = None

    def _possible(self, k: int, j: int, both: bool) -> tuple[list[Trajectory], list[Disk]]:
        """Trajectories and disks that hold whatever UAV j flies from t_k on.

        Trajectories and disks that hold whatever UAV j flies from t_k on (for the check at step
        k of a proposal): its step k-1 trajectory in force (and proposal when `both`) if heard,
        else what it can reach since it was last known, or, if gone, its last commitments (their
        loiters' disks are `failsafe_loiters`)."""
        s = self.latest[j]
        if k == 0:
            return [s.committed] if s.committed is not None else [], []
        msg = self.fresh.get(j)
        if msg is not None:
            committed, proposal = msg.state.committed, msg.state.proposal
            trajs = [] if committed is None else [committed]
            if both and proposal is not None:
                trajs.append(proposal)
            return trajs, []
        if j in self.dead:
            return [t for t in (s.committed, s.proposal) if t is not None], []
        r = self.limits.reach
        return [], [(s.x, s.y, (k + 1 - s.stamp) * r.step + r.extent)]

    def failsafe_loiters(self, j: int) -> list[Disk]:
        """Where the aircraft of gone UAV j circles once its failsafe fires.

        Where the aircraft of gone UAV j circles once its failsafe fires: `safety.failsafe_reach`
        about the centre of the loiter of its last trajectory in force, of its last proposal, or of
        the trajectory in force it announced before (its companion moves the failsafe mission to the
        loiter of its trajectory in force after announcing it, so a companion that dies in between
        leaves the one before on the autopilot; `companion.node.failsafe`). A vehicle its companion
        does not steer: `adrift_reach` about its latest report."""
        s = self.latest[j]
        if not s.steered:
            return [(s.x, s.y, self.adrift_reach)]
        return [
            (*self.limits.loiter_circle(t)[:2], self.failsafe)
            for t in (s.committed, s.proposal, self.before.get(j))
            if t is not None
        ]

    def failsafe_regions(self, k: int, j: int) -> list[tuple[Disk, FloatArray]]:
        """Where the aircraft of gone UAV j flies from its companion's death on.

        Where the aircraft of gone UAV j flies from its companion's death on (`clears_loiters`):
        for each of its `failsafe_loiters`, the fan of each path it may have been flying (its last
        trajectory in force and proposal, from their anchors to their loiters' entries) about that
        loiter's centre, inflated by `fan_reach`; once it must be circling (`settle` steps after
        its last message), the disks of `failsafe_loiters` alone (an empty path). A vehicle its
        companion does not steer: the disk about its latest report, and the region of the last
        trajectory in force it had (its companion may have lost the link to it, whose failsafe
        then flies that trajectory's loiter)."""
        s = self.latest[j]
        disks = self.failsafe_loiters(j)
        lim = self.limits
        plain: list[tuple[Disk, FloatArray]] = [(d, np.zeros((0, 2))) for d in disks]
        if not s.steered:  # a lost vehicle link leaves its autopilot's failsafe on its last trajectory
            last = self.before.get(j)
            if last is None:
                return plain
            return [*plain, ((*lim.loiter_circle(last)[:2], self.fan_reach), lim.planned_path(last))]
        if k - s.stamp > self.settle:
            return plain
        paths = [lim.planned_path(t) for t in (s.committed, s.proposal) if t is not None]
        return [((cx, cy, self.fan_reach), path) for cx, cy, _ in disks for path in paths]

    def _children(self) -> set[int]:
        """The UAVs heard naming this one a parent, not taken as gone (kept until they may change)."""
        if self._kids is None:
            self._kids = {
                c for c, msg in self.fresh.items() if self.uav in msg.parents and c not in self.dead
            }
        return self._kids

    def _gather(self, k: int, x: float, y: float) -> None:
        """Expand what every other UAV may fly from t_k on, once for this step's checks.

        What every other UAV may fly from t_k on (`_possible`, both trajectories), expanded once
        for this step's checks over steps k..k + window + 1, with their owners. UAVs too far from
        (x, y), this UAV's position at t_k, to matter for a trajectory anchored within a step of it
        are left out (every point of a trajectory lies within `Reach.extent` of its anchor), unless
        tethered or gone (their failsafe loiters are gathered too)."""
        lim = self.limits
        r = lim.reach
        kernel_row = lim.kernel_row
        near_reach, far_reach, anchored = self._reaches
        links = set(self.parents) | self._children()
        fresh, dead, before = self.fresh, self.dead, self.before
        table: list[float] = []  # per row: its kernel row, owner, in force, loiter entry, clause
        lone: list[float] = []  # per lone trajectory: its kernel row, the row of its owner's in force
        count = 0
        owners: set[int] = set()
        disks: list[tuple[float, float, float, float]] = []  # owner, cx, cy, r
        regions: list[tuple[Disk, FloatArray]] = []
        for j, latest in self.latest.items():
            mine, dsk = self._possible(k, j, both=True)
            guarded = self.near[j]  # its failures can reach this UAV's layer
            gone = j in dead
            if gone and k > 0:
                if guarded or not latest.steered:  # nobody steers it: it may leave its layer
                    regions += self.failsafe_regions(k, j)
            elif j not in links:
                s = fresh[j].state if j in fresh else latest
                reach = near_reach if guarded else far_reach
                for d in dsk:
                    reach = max(reach, anchored + d[2] + lim.disk_separation)
                if math.hypot(s.x - x, s.y - y) > reach:
                    continue
            if not mine:
                if dsk:
                    disks += [(j, *d) for d in dsk]
                continue
            if guarded and not gone and j in before:
                lone += kernel_row(before[j])[0]
                lone += (count, 0, 0, 0)  # the row of j's trajectory in force, mine[0]
            owners.add(j)
            for t in mine:
                row, entry = kernel_row(t)
                table += row
                table += (j, t is mine[0], entry, guarded)
                count += 1
            if dsk:
                disks += [(j, *d) for d in dsk]
        if lone:
            table += lone
        rows = np.array(table, dtype=float).reshape(-1, HEAD + lim.horizon + EXTRA)
        gathered_rows(rows, count, k, r.window, lim.kinematics_args, *self._buffers)
        if disks:
            at = np.array(disks, dtype=float)
            held = (np.ascontiguousarray(at[:, 1:]), np.array([j for j, *_ in disks], dtype=np.int64))
        else:
            held = self._no_disks
        self._gathered = (rows, count, k, *self._buffers, *held)
        self._gathered_owners = owners
        if not regions:  # (empty arrays are never written to)
            self._regions = self._no_regions
            return
        fans = np.zeros((len(regions), lim.horizon + 1, 2))
        for i, (_, path) in enumerate(regions):
            fans[i, : len(path)] = path
        self._regions = (
            np.array([d for d, _ in regions], dtype=float).reshape(-1, 3),
            fans,
            np.array([len(p) for _, p in regions], dtype=np.int64),
        )

    def _links(self) -> IntArray:
        """The tethered UAVs (parents and children) not taken as gone, ascending."""
        if self._tethers != self.parents:
            ids = sorted((set(self.parents) | self._children()) - self.dead)
            if ids != self._link_ids:  # (the array is never written to)
                self._link_ids, self._link_array = ids, np.array(ids, dtype=np.int64)
            self._tethers = self.parents
        return self._link_array

    # -- the protocol, step by step --------------------------------------------------------------
    def resolve(self, k: int, x: float, y: float, heading: float) -> Trajectory:
        """T_i^k: the pending proposal if it may still be switched to, else the trajectory in force.

        T_i^k: switch to the pending proposal if it is still compatible with everything the others
        may fly (see the module docstring), anchored at the UAV's pose at t_k."""
        lim = self.limits
        turn = lim.reach.loiter_turn
        chosen = self.inforce
        self._gather(k, x, y)
        links = self._links()
        if self.proposal is not None and self.proposal.start == k:
            (proposed, pe), (held, ie) = (
                self.limits.kernel_row(self.proposal),
                self.limits.kernel_row(self.inforce),
            )
            both = np.array([proposed, held], dtype=float)
            if may_switch_from(
                self._gathered, links, self.uav, both, k, pe - k, ie - k, self._regions, self.rules
            ):
                chosen = self.proposal
                self.accepted += 1
            else:
                self.rejected += 1
        self.inforce = self._flyable(k, chosen.reanchored(k, x, y, heading, turn), links)
        self.proposal = None
        return self.inforce

    def loitering(self) -> bool:
        """Whether the trajectory in force takes only its loiter turns from now on."""
        turn = self.inforce.loiter * self.limits.reach.loiter_turn
        return all(abs(t - turn) < 1e-9 for t in self.inforce.turns)

    def _flyable(self, k: int, trajectory: Trajectory, links: IntArray) -> Trajectory:
        """`trajectory` if it is flyable from its anchor, else the first start contingency that is.

        `trajectory` if it is inside the fence and compatible with the others' trajectories in force
        and its tethers, else a start contingency from its anchor that is (straight for M >= s >= 0
        steps, then loiter).

        A UAV that flies its trajectories exactly never needs this (the invariant); a flown vehicle
        that strayed from its plan (a companion that started late, a gust) is re-anchored where it
        is, which may put its promise outside the fence or across another's: it then takes the
        first contingency that is not, or keeps its trajectory if none is."""
        # the others' trajectories in force at k-1: whatever each decides at k, the invariant makes ours
        # compatible with them (their proposals are theirs to check; a disk only bounds what is unknown)
        row, entry = self.limits.kernel_row(trajectory)
        rows = np.array([row], dtype=float)
        if flyable_from(self._gathered, links, self.uav, rows[0], k, self.rules):
            self._held = (trajectory, rows, entry)
            return trajectory
        options = self._contingency_rows.copy()
        options[:, :4] = (k, trajectory.x, trajectory.y, trajectory.heading)
        for (turns, side), row in zip(self._contingencies, options, strict=True):
            if flyable_from(self._gathered, links, self.uav, row, k, self.rules):
                self.recovered += 1
                return Trajectory(k, trajectory.x, trajectory.y, trajectory.heading, turns, side)
        return trajectory

    def next_pose(self, x: float, y: float, heading: float) -> tuple[float, float, float]:
        """The pose at t_k+1 when flying the trajectory in force from (x, y, heading) at t_k."""
        lim = self.limits
        turn = self.inforce.turn_at(self.inforce.start, lim.reach.loiter_turn)
        return step_pose(x, y, heading, turn, lim.grid, lim.speed, lim.dt, lim.cell)

    def update_parents(self, k: int, position: FloatArray) -> None:
        """Make-before-break re-tethering to a nearer UAV of a lower rank.

        Make-before-break re-tethering: name the nearest UAV of a lower rank as a second parent
        when it is clearly nearer than the parent and the trajectories in force keep the link; drop
        the old parent once the new one has heard it named; drop parents that are gone."""
        dead = self.dead
        parents = self.parents = tuple(p for p in self.parents if p not in dead)
        if len(parents) == 2:
            new = parents[1]
            msg = self.fresh.get(new)
            if msg is not None and self.uav in msg.heard and k - ACK_STEPS >= self.parent_since:
                self.parents = (new,)
            return
        ranks, latest = self.ranks, self.latest
        rank = ranks[self.uav]
        if rank == 0:
            return
        lim = self.limits
        px, py = float(position[0]), float(position[1])  # how far a UAV was last known to be from it
        current = math.hypot(latest[parents[0]].x - px, latest[parents[0]].y - py) if parents else math.inf
        bound = current - 0.1 * lim.link
        better: list[tuple[float, int]] = []
        for j in self.fresh:
            if ranks[j] < rank and j not in parents and j not in dead:
                d = math.hypot(latest[j].x - px, latest[j].y - py)
                if d < bound:
                    better.append((d, j))
        better.sort(key=lambda pair: pair[0])  # stable: ties keep the order heard
        for _, j in better:
            trajs, _ = self._possible(k, j, both=True)
            pts = lim.expand(lim.rows([self.inforce]), k)[0]
            tethers = lim.expand(lim.rows(trajs), k)
            empty_o, empty_d = np.zeros((0, lim.reach.window + 1, 2)), np.zeros((0, 3))
            if compatible(pts, empty_o, empty_d, tethers, empty_d, *lim.clearances):
                self.parents = (*self.parents, j)
                self.parent_since = k
                if j not in self._gathered_owners:  # left out as too far to matter: not as a tether
                    self._gather(k, float(position[0]), float(position[1]))
                return

    def first_allowed(self, k: int, pose: tuple[float, float, float], order: np.ndarray) -> tuple[int, int]:
        """The first path of eq. 23 in the RHC's order that may be proposed, and its side.

        The first path of eq. 23 (`PathTree.sequences`) in `order` (the RHC's preference) whose
        trajectory from `pose` at t_k+1 may be proposed (in the fence, and compatible with what the
        others may fly then), and its loiter side; (-1, 0) if none."""
        lim = self.limits
        x, y, heading = pose
        h = round(heading / (math.pi / 4)) % 8 if lim.grid else 0
        c, s = (1.0, 0.0) if lim.grid else (math.cos(heading), math.sin(heading))
        towards = self._turn_towards(x, y)
        held, reference, entry = self._held
        if held is not self.inforce:
            row, entry = self.limits.kernel_row(self.inforce)
            reference = np.array([row], dtype=float)
        shapes, centres = self._shapes[h], self._shape_centres[h]
        candidates: CandidatesArgs = (order, shapes, centres, x, y, c, s, towards, *self._radii[h])
        best, side = first_allowed_from(
            self._gathered,
            self._links(),
            self.uav,
            k + 1,
            reference,  # a proposal not clearing the regions keeps as far from them as this
            entry - (k + 1),
            candidates,
            self._regions,
            self.rules,
        )
        self.first_asked += 1
        self.first_refused += bool(len(order)) and best != order[0]
        return best, side

    def _turn_towards(self, x: float, y: float) -> FloatArray:
        """The point a new proposal's loiter turns towards: away from a near UAV.

        The point a new proposal's loiter should turn towards (that side is tried first; both are
        checked): far away from the nearest other UAV within `SIDE_RANGE` of (x, y) on a near layer
        (`SafetyPlan.near`) that is not taken as gone (its last position may be stale), so that the
        two UAVs' failsafe regions, each reaching `failsafe_reach` + `failsafe_stray` about its
        loiter's centre, open apart; else the region's centroid, which keeps loiters inside.
        `SIDE_RANGE` is the range measured on the paper's scenarios (git show e1523f9:docs/results.md,
        "The loiter side")."""
        nearest, at = math.inf, (x, y)
        for j, s in self.latest.items():
            d = math.hypot(x - s.x, y - s.y)
            if self.near[j] and j not in self.dead and d < nearest:
                nearest, at = d, (s.x, s.y)
        if not 0.0 < nearest <= SIDE_RANGE:  # none near, or no direction to turn from
            return self._centre
        return np.array([x + (x - at[0]) / nearest * FAR, y + (y - at[1]) / nearest * FAR])

    def propose(self, proposal: Trajectory | None) -> None:
        """Announce `proposal` (P_i^k), to be resolved at step k + 1."""
        self.proposal = proposal
