"""The per-UAV agent: `step(observation, inbox) -> (command, outbox)`.

One Agent runs the whole distributed algorithm for one UAV. It keeps its own uncertainty map and
its knowledge of the other UAVs, and cooperates only through the messages of
`companion.core.messages`, so the batch engine and the companion process drive it identically.

Timing: the observation of step k carries the UAV's pose and camera detections at t_k; the inbox
holds what neighbours sent at step k-1 (one step of radio latency); the command is the turn for
[t_k, t_{k+1}], and the outbox is stamped k.

Mission planning (algorithm "proposed"): a UAV without a task announces its bids (eq. 15) at step
k; at k+1 every bidder runs the same local auction (Algorithm 2) over the bids it heard and the
tasks not held by anyone it knows of, and takes the task the auction gives it. Claims travel
multi-hop in ClaimsMsg; when two UAVs claim one task the lower claim priority drops it and bids
again (synchronisation). A held task is reevaluated every step (eqs. 20-21).
"""

from __future__ import annotations

from collections.abc import Iterable
from functools import reduce
from itertools import chain
from operator import or_

import msgspec
import numpy as np
from numba import njit

from companion.core import pheromone as phero
from companion.core.auction import claim_priority, local_auction
from companion.core.commitment import Commitments
from companion.core.connectivity import kruskal_mst, mst_neighbours
from companion.core.geometry import FloatArray
from companion.core.messages import (
    BidsMsg,
    ClaimsMsg,
    CoverageMsg,
    Message,
    StateMsg,
    UavState,
)
from companion.core.rhc import rank_candidates, rank_grid_candidates
from companion.core.tasks import bid_rewards, keep_task, task_completion, task_costs
from companion.core.trajectory import Trajectory, step_pose
from companion.core.uncertainty import apply_looks, mark_seen
from companion.core.world import World


class Observation(msgspec.Struct, frozen=True, kw_only=True):
    """The UAV's own pose at step k (local frame, heading CCW from east), its camera's detections,
    and whether its vehicle flies what the agent commands (False: a pilot, a failsafe or the guard's
    way back inside flies it; the agent then commits to nothing: `UavState.steered`). `closing`: the
    mission is over; the agent proposes nothing new and commands its trajectory in force, which ends
    in a loiter that every peer's trajectory in force keeps clear of (the companion's hand-over)."""

    step: int
    x: float
    y: float
    heading: float
    detections: tuple[tuple[float, float], ...] = ()
    steered: bool = True
    closing: bool = False


class StepDelta(msgspec.Struct, frozen=True, array_like=True):
    """What one step changed in an agent's own knowledge (`Agent.last`): every FOV cell applied to its
    map (its own and its neighbours', in order), the cells newly known to hold a target, and its task
    and commitments after the step. Replaying the deltas of steps k+1..k' on the snapshot of step k
    (`Agent.replay`) gives the agent's map, targets, task and trajectory in force of step k'."""

    step: int
    looks: tuple[int, ...]
    found: tuple[int, ...]
    task: int
    task_reward: float
    inforce: Trajectory
    parents: tuple[int, ...]


class AgentSnapshot(msgspec.Struct, frozen=True, array_like=True):
    """An agent's own knowledge after step `step` (`Agent.snapshot`, `Agent.restore`): its uncertainty
    map (float64, little-endian), the cells it has looked at (packed bits), the target cells it knows
    of, its task, its trajectory in force and tethers, and the pheromone field (that algorithm only).
    What it knew of the others is not kept: their next messages tell it again."""

    uav: int
    step: int
    eta: bytes
    seen: bytes
    found: tuple[int, ...]
    task: int
    task_reward: float
    inforce: Trajectory
    parents: tuple[int, ...]
    phi: bytes | None = None


class Command(msgspec.Struct, frozen=True, kw_only=True):
    """The first step of the chosen path: turn over the step, and the path for waypoint autopilots."""

    step: int
    turn: float
    heading_rate: float
    heading: float
    waypoint: tuple[float, float]
    path: tuple[tuple[float, float], ...]
    task: int = -1


@njit(cache=True)
def predict_tracks(seqs: FloatArray, stamps: np.ndarray, first: int, count: int) -> FloatArray:
    """Positions of UAVs at steps first..first+count-1 from their last states.

    `seqs[u]` is UAV u's position at its stamp followed by its planned path; past the plan the
    UAV is assumed to keep its last planned velocity.
    """
    n, length = seqs.shape[0], seqs.shape[1]
    out = np.empty((n, count, 2))
    for u in range(n):
        for t in range(count):
            i = first + t - stamps[u]
            c = min(max(i, 0), length - 1)
            for a in range(2):
                out[u, t, a] = seqs[u, c, a]
                if length >= 2:
                    out[u, t, a] += (i - c) * (seqs[u, length - 1, a] - seqs[u, length - 2, a])
    return out


@njit(cache=True)
def swarm_view(table: FloatArray, k: int, position: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The MST (eq. 26) over this UAV at `position` and the UAVs it knows of, at t_k.

    Row r of `table` holds a UAV's last state: its stamp, its position then its planned path
    (M + 1 points, x and y), its heading then the heading at each planned point (M + 1). Returns
    the MST neighbours' positions at t_k and their predicted tracks over t_k..t_{k+M}.
    """
    horizon = (table.shape[1] - 1) // 3 - 1
    stamps = table[:, 0].astype(np.int64)
    track = np.ascontiguousarray(table[:, 1 : 2 * horizon + 3]).reshape(-1, horizon + 1, 2)
    tracks = predict_tracks(track, stamps, k, horizon + 1)
    now = np.empty((table.shape[0] + 1, 2))
    now[0] = position
    now[1:] = tracks[:, 0, :]
    rows = mst_neighbours(kruskal_mst(now), 0) - 1
    return tracks[rows, 0, :], tracks[rows]


RELAY_MEMO_SIZE = 1024


def relay_set(
    me: int, own_heard: tuple[int, ...], neighbours: dict[int, tuple[int, ...]], peers: Iterable[int]
) -> tuple[int, ...]:
    """The peers whose latest state UAV `me` relays, ascending.

    Every UAV reports whom it heard first-hand at its previous step (`StateMsg.heard`); `me` knows
    the reports of the UAVs it heard this step (`neighbours`) and its own (`own_heard`). A peer p
    is relayed for a UAV l that `me` heard when l did not hear p itself, unless a UAV that l heard
    and that heard p (per the reports `me` knows) has a lower id than `me`: the lowest such UAV
    relays p to l. The true lowest one sees itself as lowest in its own view, so no pair is left
    out where the reports hold; where l is farther than two hops from p, everyone that has p
    relays. A swarm in which everyone hears everyone relays nothing.
    """
    reports = {**neighbours, me: own_heard}
    heard_by: dict[int, int] = {}  # p -> mask of the UAVs reported to have heard p
    for m, heard in reports.items():
        for p in heard:
            heard_by[p] = heard_by.get(p, 0) | 1 << m
    bit = 1 << me
    need: set[int] = set()
    for u, heard in neighbours.items():
        heard_u = reduce(or_, (1 << v for v in heard), 0)
        for p in peers:
            if p == u or p in need or heard_u >> p & 1:
                continue
            relayers = heard_u & heard_by.get(p, 0)
            if not relayers or relayers & -relayers == bit:
                need.add(p)
    return tuple(sorted(need))


class Agent:
    """The distributed cooperative search algorithm for UAV `uav` (0-based)."""

    def __init__(self, world: World, uav: int) -> None:
        m = world.mission
        self.world, self.uav = world, uav
        self.algorithm = m.algorithm.name
        n = world.grid.n_cells
        self._eta_padded = np.zeros(n + 1)  # eta followed by the 0 that FOV padding gathers (eq. 25)
        self.eta = self._eta_padded[:-1]
        self.eta[:] = m.uncertainty.eta0
        self._values = self._eta_padded if self.algorithm == "proposed" else np.zeros(n + 1)
        # no-ta scores importance s = eta Pr (eq. 12) on eta's scale: Pr relative to its peak, so that
        # eq. 22 weighs its search term against eq. 29's barriers as it does the proposed method's eta
        self._relative_prior = world.prior / max(float(world.prior.max()), np.finfo(float).tiny)
        self.seen = np.zeros(n, dtype=bool)
        self.found: set[int] = set()
        self.peers: dict[int, UavState] = {}
        self.neighbours: dict[int, tuple[int, ...]] = {}  # heard from at this step -> whom they heard
        self._heard: tuple[int, ...] = ()  # whom we reported to have heard, in our last StateMsg
        self._relay_memo: dict[tuple, tuple[int, ...]] = {}
        horizon = m.algorithm.horizon
        self._horizon = horizon
        self._rows: dict[int, tuple[float, ...]] = {}  # each peer's state as a `swarm_view` row
        self.rejected = 0
        self.task = -1
        self.task_reward = 0.0
        self.bids: tuple[float, ...] | None = None  # announced at self.bid_stamp
        self.bid_stamp = -1
        tess = world.tessellation
        self.covered = np.zeros(tess.n_tasks if tess else 0, dtype=np.int64)
        self._labels = np.append(tess.labels, -1) if tess else np.zeros(n + 1, dtype=np.int64)
        self.phi = np.zeros(n) if self.algorithm == "pheromone" else None
        self.commitments = Commitments(world, uav)
        self.last: StepDelta | None = None  # what the latest step changed (journals keep it)

    # -- inbox ---------------------------------------------------------------------------------
    def forget(self, uav: int) -> None:
        """Drop what is known of a UAV that has left (its task is free for the next auction)."""
        self.peers.pop(uav, None)
        self._rows.pop(uav, None)
        self.commitments.gone(uav)

    def _remember(self, states: Iterable[UavState]) -> None:
        """Keep the newest state of each peer, and its `swarm_view` row: a plan shorter than the
        horizon goes on at its last velocity, headings past the plan stay at the last one."""
        horizon = self._horizon
        for state in states:
            old = self.peers.get(state.uav)
            if state.uav == self.uav or (old is not None and state.stamp <= old.stamp):
                continue
            self.peers[state.uav] = state
            plan, heads = state.plan[:horizon], state.plan_headings[:horizon]
            if len(plan) < horizon:
                track = [(state.x, state.y), *plan]
                while len(track) <= horizon:
                    (x1, y1), (x2, y2) = track[-2:] if len(track) >= 2 else track * 2
                    track.append((2 * x2 - x1, 2 * y2 - y1))
                plan = track[1:]
            if len(heads) < horizon:
                heads += (heads or (state.heading,))[-1:] * (horizon - len(heads))
            flat = chain.from_iterable(plan)
            self._rows[state.uav] = (state.stamp, state.x, state.y, *flat, state.heading, *heads)

    def _ingest(self, inbox: Iterable[Message], k: int, looks: list[int]) -> dict[int, tuple[float, ...]]:
        """Sort the inbox by kind: the neighbours' FOV cells go onto `looks`, states and claims into
        what this UAV knows of the others (and its commitments: `Commitments.observe`); returns the
        bids of this auction round. Messages are validated where they enter (`messages.check`);
        here only their timing counts."""
        bids: dict[int, tuple[float, ...]] = {}
        oldest = k - self.world.mission.comms.peer_timeout_steps
        states: list[UavState] = []
        fresh: dict[int, StateMsg] = {}
        self.neighbours = neighbours = {}
        for msg in inbox:
            if msg.sender == self.uav or not oldest <= msg.stamp <= k:
                self.rejected += 1
                continue
            kind = type(msg)
            if kind is StateMsg:
                states.append(msg.state)
                if msg.stamp == k - 1:
                    neighbours[msg.sender] = msg.heard
                    fresh[msg.sender] = msg
            elif kind is CoverageMsg:
                looks += msg.cells
                if msg.detections:
                    self.found.update(msg.detections)
            elif kind is BidsMsg:
                if msg.stamp == k - 1:
                    bids[msg.sender] = msg.rewards
            else:
                states.extend(msg.known)
        self._remember(states)
        self.commitments.observe(k, fresh, states)
        for u in [u for u, s in self.peers.items() if s.stamp < oldest]:
            self.forget(u)
        return bids

    def _relay(self) -> tuple[int, ...]:
        """The peers whose latest state goes out in this step's ClaimsMsg, ascending (`relay_set`
        of this step's reports; a swarm keeps its layout for many steps, so answers are reused)."""
        if not self.neighbours:
            return ()
        key = (self._heard, tuple(self.neighbours.items()), tuple(self.peers))
        relay = self._relay_memo.get(key)
        if relay is None:
            if len(self._relay_memo) >= RELAY_MEMO_SIZE:
                self._relay_memo.clear()
            relay = self._relay_memo[key] = relay_set(self.uav, self._heard, self.neighbours, self.peers)
        return relay

    # -- map -----------------------------------------------------------------------------------
    def _update_map(self, looks: list[int]) -> None:
        """Eqs. 10-11 and the covered-cell count of each task (eq. 20) for the FOV cells `looks`."""
        cells = np.array(looks, dtype=np.int64)
        apply_looks(self.eta, cells, self.world.mission.uncertainty.gamma)
        mark_seen(self.seen, self.covered, self._labels, cells)

    # -- mission planning ----------------------------------------------------------------------
    def _my_bids(self, position: FloatArray, mst_nbrs: FloatArray) -> tuple[float, ...]:
        """Eq. 15 rewards; zero for tasks this UAV could not keep (eq. 21: complete or too costly)
        and, when it holds a task, for tasks not worth more than the task it holds (Algorithm 2's
        greedy bidder would not take them: lines 10-11)."""
        w, tess = self.world, self.world.tessellation
        assert tess is not None
        a = w.mission.algorithm
        held = self.task
        out = bid_rewards(
            self.eta, w.prior, tess.labels, self.covered, tess.cell_counts, a.v_max, a.c_max, position,
            mst_nbrs, tess.generators, tess.areas, w.costs, held,
        )  # fmt: skip
        return tuple(out.tolist())

    def _plan_task(self, k: int, position: FloatArray, mst_nbrs: FloatArray, bids: dict) -> bool:
        """Algorithm 2 + synchronisation + eqs. 20-21; returns True when bids go out this step.

        Every UAV is a greedy bidder (Algorithm 2): it announces its rewards at step k (`BidsMsg`),
        and at k+1 runs the local auction over the bids it heard, the tasks held by the UAVs it knows
        of removed; a task it wins replaces the one it holds (its bids already exclude tasks worth
        less). The held task is then reevaluated (eqs. 20-21) and dropped on a conflicting claim of
        a higher priority."""
        w, tess = self.world, self.world.tessellation
        assert tess is not None
        a = w.mission.algorithm
        if self.bids is not None and self.bid_stamp == k - 1:
            bidders = [self.uav, *sorted(bids)]
            table = np.array([self.bids, *(bids[u] for u in sorted(bids))])
            available = np.ones(tess.n_tasks, dtype=bool)
            for s in self.peers.values():
                if s.task >= 0:
                    available[s.task] = False
            if self.task >= 0:
                available[self.task] = False
            won = local_auction(bidders, table, available).get(self.uav)
            if won is not None:
                self.task, self.task_reward = won
        if self.task >= 0:
            mine = claim_priority(self.task_reward, self.uav)
            lost = any(
                s.task == self.task and claim_priority(s.task_reward, u) > mine for u, s in self.peers.items()
            )
            j = self.task
            completion = task_completion(int(self.covered[j]), int(tess.cell_counts[j]))
            _, holding = task_costs(
                position, mst_nbrs, tess.generators[j : j + 1], tess.areas[j : j + 1], w.costs
            )
            cost = float(holding[0])
            if lost or not keep_task(completion, cost, a.v_max, a.c_max):
                self.task, self.task_reward = -1, 0.0
        self.bids = None
        bids = self._my_bids(position, mst_nbrs)
        if max(bids, default=0.0) > 0:  # nothing left to win: no auction
            self.bids, self.bid_stamp = bids, k
        return self.bids is not None

    # -- step ----------------------------------------------------------------------------------
    def _continuous_path_cells(self, pts: FloatArray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Continuous mode: the cell under each path point, the FOV cells of each point (eq. 3), and
        the in-region prefix (grid mode does all this inside `choose_grid_path`).

        A path's last point must also leave room to turn back (a turning diameter from the
        boundary), else the path counts one point short: three steps of eq. 2 cannot see the
        U-turn a corner needs.
        """
        grid, kin = self.world.grid, self.world.kinematics
        cells = grid.cell_at(pts)
        depth = -np.max(pts @ grid.region.normals.T - grid.region.offsets, axis=-1)  # metres inside
        prefix = np.cumprod(depth >= 0, axis=1).sum(axis=1)
        diameter = 2 * kin.speed * kin.dt / kin.turn_limit
        prefix -= (prefix == pts.shape[1]) & (depth[:, -1] < diameter)
        return cells, grid.fov_cells(pts), prefix

    def _swarm(self, k: int, position: FloatArray) -> tuple[FloatArray, FloatArray]:
        """`swarm_view` of what this UAV knows, at t_k (eq. 26 and the neighbours' predicted motion)."""
        if not self._rows:
            return np.zeros((0, 2)), np.zeros((0, self._horizon + 1, 2))
        table = np.array([self._rows[u] for u in sorted(self._rows)])
        return swarm_view(table, k, position)

    def step(self, obs: Observation, inbox: Iterable[Message]) -> tuple[Command, list[Message]]:
        w, m = self.world, self.world.mission
        grid, k, a = w.grid, obs.step, m.algorithm
        looks = grid.fov_cell_list((obs.x, obs.y)).tolist()
        own_cells = tuple(looks)
        known = set(self.found)
        bids = self._ingest(inbox, k, looks)
        self._update_map(looks)
        if obs.detections:
            detected = grid.cell_at(np.array(obs.detections, dtype=float))
            own_detections = tuple(sorted({int(c) for c in detected if c >= 0}))
            self.found.update(own_detections)
        else:
            own_detections = ()

        # safety layer: the trajectory in force for [t_k, t_k+1], then plan from the pose at t_k+1
        safety = self.commitments
        inforce = safety.resolve(k, obs.x, obs.y, obs.heading)
        x1, y1, h1 = safety.next_pose(obs.x, obs.y, obs.heading)
        nxt = np.array([x1, y1])
        mst_now, nbr_tracks = self._swarm(k + 1, nxt)
        announce = self._plan_task(k, nxt, mst_now, bids) if self.algorithm == "proposed" else False
        safety.update_parents(k, np.array([obs.x, obs.y]))

        # RHC: eq. 24 over every path of eq. 23, best first (eq. 22); the safety layer takes the first
        # it allows
        if self.algorithm == "no-ta":
            self._values[:-1] = self.eta * self._relative_prior
        elif self.phi is not None:
            self.phi = phero.step_field(grid, self.phi, self.eta, w.prior, a.pheromone, self._values)
        tess = w.tessellation
        if self.task >= 0 and tess is not None:
            region = (self.task, tess.generators[self.task], float(tess.circumradii[self.task]))
        else:
            region = (-1, nxt, 1.0)
        c = m.comms
        rest = (
            a.delta,
            a.chi,
            nbr_tracks,
            (c.range, c.attraction, c.safety, c.repulsion),
            grid.region.normals,
            grid.region.offsets,
            grid.cell_size,
        )
        if w.kinematics.mode == "grid":
            offsets = w.paths.offsets_from(h1)
            order, pts = rank_grid_candidates(
                x1, y1, offsets, grid.x0, grid.y0, grid.lattice, grid.fov_table, self._values,
                self._labels, *region, *rest,
            )  # fmt: skip
        else:
            pts = w.paths.expand(x1, y1, h1)
            cells, fov, prefix = self._continuous_path_cells(pts)
            labels = self._labels[cells] if region[0] >= 0 else cells  # cell -1 reads the trailing -1
            order = rank_candidates(pts, fov, prefix, self._values, labels, *region, *rest)
        best, side = safety.first_allowed(k, (x1, y1, h1), order)
        path = pts[max(best, 0)]

        horizon, turn = self._horizon, float(inforce.turns[0])
        if best >= 0 and not obs.closing:
            turns = tuple(w.paths.sequences[best].tolist())
            proposal = Trajectory(k + 1, x1, y1, h1, turns, side)
            plan = ((x1, y1), *map(tuple, path[: horizon - 1].tolist()))
            plan_headings = (h1, *w.paths.headings_along(h1, best)[: horizon - 1])
        else:
            proposal = None
            ahead = inforce.reanchored(k + 1, x1, y1, h1, safety.limits.reach.loiter_turn)
            plan, plan_headings = self._track_of(ahead)
        safety.propose(proposal if obs.steered else None)
        command = Command(
            step=k,
            turn=turn,
            heading_rate=turn / w.kinematics.dt,
            heading=h1,
            waypoint=(x1, y1),
            path=plan,
            task=self.task,
        )
        if obs.steered:
            me = UavState(
                self.uav, k, obs.x, obs.y, obs.heading, plan, self.task, self.task_reward, plan_headings,
                inforce, proposal,
            )  # fmt: skip
        else:  # nothing to promise: the others keep clear of where it is (`Commitments`)
            me = UavState(
                self.uav, k, obs.x, obs.y, obs.heading, (), self.task, self.task_reward, steered=False
            )
        head = {"sender": self.uav, "stamp": k, "x": obs.x, "y": obs.y}
        heard, relay = tuple(sorted(self.neighbours)), self._relay()
        self._heard = heard
        found = tuple(sorted(self.found))  # every target known, not only this step's: late joiners catch up
        outbox: list[Message] = [
            StateMsg(**head, state=me, heard=heard, parents=safety.parents),
            CoverageMsg(**head, cells=own_cells, detections=found),
        ]
        if relay:
            outbox.append(ClaimsMsg(**head, known=tuple(self.peers[u] for u in relay)))
        if announce:
            assert self.bids is not None
            outbox.append(BidsMsg(**head, rewards=self.bids))
        new = tuple(c for c in found if c not in known)
        self.last = StepDelta(k, tuple(looks), new, self.task, self.task_reward, inforce, safety.parents)
        return command, outbox

    # -- snapshot and restore ------------------------------------------------------------------
    def snapshot(self) -> AgentSnapshot:
        """This agent's own knowledge after its latest step (`AgentSnapshot`)."""
        c = self.commitments
        step = self.last.step if self.last is not None else -1
        phi = None if self.phi is None else self.phi.astype("<f8").tobytes()
        return AgentSnapshot(
            self.uav, step, self.eta.astype("<f8").tobytes(), np.packbits(self.seen).tobytes(),
            tuple(sorted(self.found)), self.task, self.task_reward, c.inforce, c.parents, phi,
        )  # fmt: skip

    def restore(self, snap: AgentSnapshot) -> None:
        """Take back the knowledge of `snap` (of this UAV and world); raises ValueError if it does not fit."""
        n = self.eta.shape[0]
        if snap.uav != self.uav or len(snap.eta) != 8 * n or len(snap.seen) != (n + 7) // 8:
            raise ValueError(f"snapshot of uav {snap.uav} with {len(snap.eta) // 8} cells does not fit")
        if (snap.phi is None) != (self.phi is None) or (snap.phi is not None and len(snap.phi) != 8 * n):
            raise ValueError("snapshot of another algorithm")
        self.eta[:] = np.frombuffer(snap.eta, dtype="<f8")
        self.seen[:] = np.unpackbits(np.frombuffer(snap.seen, dtype=np.uint8), count=n).astype(bool)
        if self.covered.size:
            self.covered[:] = np.bincount(self._labels[:-1][self.seen], minlength=self.covered.size)
        if snap.phi is not None:
            self.phi = np.frombuffer(snap.phi, dtype="<f8").copy()
        self.found = set(snap.found)
        self._restart(snap.step, snap.task, snap.task_reward, snap.inforce, snap.parents)

    def replay(self, delta: StepDelta) -> None:
        """Apply a later step's delta to a restored agent, exactly as the step changed it."""
        self._update_map(list(delta.looks))
        self.found.update(delta.found)
        if self.phi is not None:
            w = self.world
            self.phi = phero.step_field(
                w.grid, self.phi, self.eta, w.prior, w.mission.algorithm.pheromone, self._values
            )
        self._restart(delta.step, delta.task, delta.task_reward, delta.inforce, delta.parents)

    def _restart(self, step: int, task: int, reward: float, inforce: Trajectory, parents: tuple) -> None:
        self.task, self.task_reward = task, reward
        self.bids, self.bid_stamp = None, -1
        c = self.commitments
        c.inforce, c.proposal, c.parents = inforce, None, tuple(parents)
        self.last = StepDelta(step, (), (), task, reward, inforce, tuple(parents))

    def _track_of(self, trajectory: Trajectory) -> tuple[tuple[tuple[float, float], ...], tuple[float, ...]]:
        """The first M points of a trajectory (from its anchor on) and the heading at each."""
        lim = self.commitments.limits
        x, y, h = trajectory.x, trajectory.y, trajectory.heading
        points, headings = [], []
        for i in range(self._horizon):
            points.append((x, y))
            headings.append(h)
            turn = trajectory.turn_at(trajectory.start + i, lim.reach.loiter_turn)
            x, y, h = step_pose(x, y, h, turn, lim.grid, lim.speed, lim.dt, lim.cell)
        return tuple(points), tuple(headings)
