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

from array import array
from collections.abc import Iterable, MutableSequence
from itertools import chain

import numpy as np

from companion.core import pheromone as phero
from companion.core.agent_io import AgentSnapshot, Command, Observation, StepDelta
from companion.core.belief import Belief
from companion.core.commitment import Commitments
from companion.core.geometry import FloatArray, IntArray
from companion.core.messages import (
    BidsMsg,
    ClaimsMsg,
    CoverageMsg,
    Message,
    StateMsg,
    UavState,
)
from companion.core.relay import RELAY_MEMO_SIZE, relay_set
from companion.core.rhc import (
    GridCells,
    ScoreWeights,
    TaskRegion,
    continuous_path_cells,
    rank_candidates,
    rank_grid_candidates,
)
from companion.core.routes import STRAIGHT
from companion.core.sensing import LLR_QUANTUM, with_reports
from companion.core.swarm_view import swarm_view
from companion.core.task_planning import Bids, TaskPlanning
from companion.core.tasks import TaskSet
from companion.core.trajectory import Trajectory
from companion.core.uncertainty import look_map
from companion.core.world import World

__all__ = ["Agent", "AgentSnapshot", "Command", "Observation", "StepDelta"]

Track = tuple[tuple[float, float], ...]  # points of a plan, from its anchor on


class Agent(TaskPlanning):
    """The distributed cooperative search algorithm for UAV `uav` (0-based)."""

    def __init__(self, world: World, uav: int) -> None:
        m = world.mission
        self.world, self.uav = world, uav
        self._grid, self._dt = world.grid, world.kinematics.dt
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
        self.belief = Belief(world.prior, m.n_uavs, uav, m.sensor.confirm, m.sensor.clear)
        s = world.sensor
        self._sensor = (s.pd, s.pd_edge, s.pf, s.radius)  # a plain tuple: numba types it faster
        self._gamma = m.uncertainty.gamma
        self.found: set[int] = set()  # cells confirmed (`Belief.confirmed`)
        self._found: tuple[int, ...] = ()  # `found` ascending
        self._misses = np.zeros(0, dtype=np.bool_)  # no camera report (`_sense`)
        self.candidates = np.zeros(0, dtype=np.int64)  # cells a detection left undecided
        self._settled = -1  # the belief's version `_settle` last read
        self._relayed: dict[int, tuple[int, ...]] = {}  # each neighbour's records, as last read
        self.peers: dict[int, UavState] = {}
        self.neighbours: dict[int, tuple[int, ...]] = {}  # heard from at this step -> whom they heard
        self._heard: tuple[int, ...] = ()  # whom we reported to have heard, in our last StateMsg
        self._relay_memo: dict[tuple, tuple[int, ...]] = {}
        horizon = m.algorithm.horizon
        self._horizon = horizon
        self._rows: dict[int, tuple[float, ...]] = {}  # each peer's state as a `swarm_view` row
        self._order: list[int] = []  # `_rows`' keys ascending; empty once they changed
        self._timeout = m.comms.peer_timeout_steps
        self._turns: dict[int, tuple[float, ...]] = {}  # each path's turns (`_plan_of`), as read
        self.rejected = 0
        self.task = -1
        self.task_reward = 0.0
        self.bids: Bids | None = None  # announced at self.bid_stamp
        self.bid_stamp = -1
        tess = world.tessellation
        self.covered = np.zeros(tess.n_tasks if tess else 0, dtype=np.int64)
        self._labels = np.append(tess.labels, -1) if tess else np.zeros(n + 1, dtype=np.int64)
        self.phi = np.zeros(n) if self.algorithm == "pheromone" else None
        grid, c = world.grid, m.comms
        self._grid_cells: GridCells = (grid.x0, grid.y0, grid.lattice, grid.fov_table)
        self._weights: ScoreWeights = (
            m.algorithm.delta,
            m.algorithm.chi,
            (c.range, c.attraction, c.safety, c.repulsion),
            grid.region.normals,
            grid.region.offsets,
            grid.cell_size,
        )
        self._tasks: TaskSet | None = (
            (tess.labels, tess.cell_counts, tess.generators, tess.areas, tess.routes) if tess else None
        )
        self.commitments = Commitments(world, uav)
        self._last: StepDelta | tuple | None = None  # `last`, or the parts it is built from
        self.newly_confirmed: tuple[int, ...] = ()  # cells the latest step confirmed

    # -- inbox ---------------------------------------------------------------------------------
    def forget(self, uav: int) -> None:
        """Drop what is known of a UAV that has left (its task is free for the next auction)."""
        self.peers.pop(uav, None)
        self._rows.pop(uav, None)
        self._order = []
        self.commitments.gone(uav)

    def _remember(self, states: Iterable[UavState]) -> None:
        """Keep the newest state of each peer and its `swarm_view` row.

        Keep the newest state of each peer, and its `swarm_view` row: a plan shorter than the
        horizon goes on at its last velocity, headings past the plan stay at the last one."""
        horizon, peers, rows, me = self._horizon, self.peers, self._rows, self.uav
        for state in states:
            u = state.uav
            old = peers.get(u)
            if u == me or (old is not None and state.stamp <= old.stamp):
                continue
            peers[u] = state
            plan, heads = state.plan[:horizon], state.plan_headings[:horizon]
            if len(plan) < horizon:
                track = [(state.x, state.y), *plan]
                while len(track) <= horizon:
                    (x1, y1), (x2, y2) = track[-2:] if len(track) >= 2 else track * 2
                    track.append((2 * x2 - x1, 2 * y2 - y1))
                plan = tuple(track[1:])
            if len(heads) < horizon:
                heads += (heads or (state.heading,))[-1:] * (horizon - len(heads))
            if old is None:
                self._order = []
            flat = chain.from_iterable(plan)
            rows[u] = (state.stamp, state.x, state.y, *flat, state.heading, *heads)

    def _ingest(
        self, inbox: Iterable[Message], k: int, looks: MutableSequence[int], coverage: list[CoverageMsg]
    ) -> dict[int, Bids]:
        """Sort the inbox by kind into looks, states and claims; return this round's bids.

        Sort the inbox by kind: the neighbours' FOV cells go onto `looks` and their coverage messages
        onto `coverage` (their evidence, fused after this UAV's own looks), states and claims into
        what this UAV knows of the others (and its commitments: `Commitments.observe`); returns the
        bids of this auction round. Messages are validated where they enter (`messages.check`);
        here only their timing counts."""
        bids: dict[int, Bids] = {}
        oldest, me, previous = k - self._timeout, self.uav, k - 1
        states: list[UavState] = []
        fresh: dict[int, StateMsg] = {}
        self.neighbours = neighbours = {}
        for msg in inbox:
            if msg.sender == me or not oldest <= msg.stamp <= k:
                self.rejected += 1
            elif type(msg) is StateMsg:
                states.append(msg.state)
                if msg.stamp == previous:
                    neighbours[msg.sender] = msg.heard
                    fresh[msg.sender] = msg
            elif type(msg) is CoverageMsg:
                looks.extend(msg.cells)
                coverage.append(msg)
            elif type(msg) is BidsMsg:
                if msg.stamp == previous:
                    bids[msg.sender] = (msg.rewards, msg.confirm, msg.confirm_rewards)
            else:
                assert isinstance(msg, ClaimsMsg)
                states.extend(msg.known)
        self._remember(states)
        self.commitments.observe(k, fresh, states)
        for u in [u for u, s in self.peers.items() if s.stamp < oldest]:
            self.forget(u)
        return bids

    def _relay(self) -> tuple[int, ...]:
        """The peers whose latest state goes out in this step's ClaimsMsg (`relay_set`), memoised."""
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
    def _update_map(self, cells: IntArray) -> None:
        """Eqs. 10-11 and the covered-cell count of each task (eq. 20) for the FOV cells `cells`."""
        look_map(self.eta, self._gamma, self.seen, self.covered, self._labels, cells)

    def _sense(
        self, obs: Observation, own: IntArray, looks: IntArray, coverage: list[CoverageMsg]
    ) -> tuple[tuple, tuple[float, ...]]:
        """Bayes' rule for this UAV's looks, then the neighbours' evidence; returns what it took.

        Every cell in view is a look, a hit where the camera reported a target (a report outside
        the FOV, from the camera's own position, is a look at its cell too). A neighbour's relayed
        records are read only when they differ from those it sent last (`Belief.merge_coverage`).
        `looks` is `own` followed by the cells of each message of `coverage`. Returns the records
        taken as `_records_taken` reads them, and this UAV's evidence at `own` after its looks (what
        its coverage message carries)."""
        grid, b = self.world.grid, self.belief
        cells = own if obs.looked else own[:0]
        if self._misses.shape[0] < cells.shape[0]:
            self._misses = np.zeros(cells.shape[0], dtype=np.bool_)
        hits = self._misses  # no report: every look a miss
        if obs.detections:
            cells, hits = with_reports(cells, grid.cell_at(np.array(obs.detections, dtype=float)))
        values = b.look(obs.step, cells, hits, (obs.x, obs.y), grid.centres, self._sensor)
        evidence = tuple((values if cells is own else b.evidence[self.uav, own]).tolist())
        mine = (cells, values)
        return (mine, b.merge_coverage(looks, own.shape[0], coverage, self._relayed)), evidence

    def _records_taken(self, step: int, taken: tuple) -> tuple[tuple[int, ...], tuple[float, ...]]:
        """The records a step's `_sense` took, as `StepDelta` keeps them: (triples, values)."""
        (cells, own_values), heard = taken
        rows = [np.stack([np.full_like(cells, self.uav), cells, np.full_like(cells, step)], axis=1)]
        values = [own_values]
        if heard is not None:
            records, heard_values, kept = heard
            rows.append(records[kept])
            values.append(np.round(heard_values[kept] / LLR_QUANTUM) * LLR_QUANTUM)
        return tuple(np.concatenate(rows).ravel().tolist()), tuple(np.concatenate(values).tolist())

    def _settle(self) -> None:
        """The cells confirmed and the candidates; a candidate's uncertainty rises to its posterior's.

        eta_p <- max(eta_p, eta_0 H(P_p)) for every candidate p, H the binary entropy in bits: a
        detection left undecided makes the cell uncertain again (docs/algorithm.md, "Imperfect
        sensing"). A perfect sensor leaves no candidate."""
        b = self.belief
        if self._settled == b.version:
            return
        self._settled = b.version
        self.candidates, confirmed = b.decided()
        if self.candidates.size:
            p = b.posterior(self.candidates)
            h = -(p * np.log2(p) + (1.0 - p) * np.log2(1.0 - p))
            eta0 = self.world.mission.uncertainty.eta0
            self.eta[self.candidates] = np.maximum(self.eta[self.candidates], eta0 * h)
        self._found = tuple(confirmed.tolist())  # ascending
        self.found = set(self._found)

    # -- mission planning ----------------------------------------------------------------------
    def _swarm(self, k: int, position: FloatArray) -> tuple[FloatArray, FloatArray]:
        """`swarm_view` of what this UAV knows, at t_k (eq. 26 and the neighbours' predicted motion)."""
        rows = self._rows
        if not rows:
            return np.zeros((0, 2)), np.zeros((0, self._horizon + 1, 2))
        order = self._order = self._order or sorted(rows)
        return swarm_view(np.array([rows[u] for u in order]), k, position)

    def step(self, obs: Observation, inbox: Iterable[Message]) -> tuple[Command, list[Message]]:
        """Step k of the algorithm: `step(observation, inbox) -> (command, outbox)`.

        Step k: fuse the inbox and the camera into the map (eqs. 10-11), resolve the trajectory in
        force, plan the task (Algorithm 2, eqs. 20-21) and the path (eq. 22) from the pose at t_k+1,
        and answer the command for [t_k, t_k+1] and the outbox stamped k."""
        k = obs.step
        own = self._grid.fov_cell_list((obs.x, obs.y))
        own_cells = tuple(own.tolist())
        looks = array("q", own.tobytes())  # int64: a buffer numpy reads without converting each int
        known = self._found
        coverage: list[CoverageMsg] = []
        bids = self._ingest(inbox, k, looks, coverage)
        cells = np.frombuffer(looks, dtype=np.int64)
        self._update_map(cells)
        taken, evidence = self._sense(obs, own, cells, coverage)
        self._settle()

        # safety layer: the trajectory in force for [t_k, t_k+1], then plan from the pose at t_k+1
        safety = self.commitments
        inforce = safety.resolve(k, obs.x, obs.y, obs.heading)
        pose = safety.next_pose(obs.x, obs.y, obs.heading)
        nxt = np.array(pose[:2])
        mst_now, nbr_tracks = self._swarm(k + 1, nxt)
        announce = self._plan_task(k, nxt, mst_now, bids) if self.algorithm == "proposed" else False
        safety.update_parents(k, np.array([obs.x, obs.y]))

        # RHC: eq. 24 over every path of eq. 23, best first (eq. 22); the safety layer takes the first
        # it allows
        order, pts = self._rank(pose, nxt, nbr_tracks)
        best, side = safety.first_allowed(k, pose, order)
        proposal, plan, plan_headings = self._plan_of(k, pose, best, side, pts[max(best, 0)], inforce, obs)
        safety.propose(proposal if obs.steered else None)
        turn = float(inforce.turns[0])
        command = Command(
            step=k,
            turn=turn,
            heading_rate=turn / self._dt,
            heading=pose[2],
            waypoint=pose[:2],
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
        found = self._found
        outbox = self._outbox(obs, me, (own_cells, evidence), found, announce)
        new = () if found is known else tuple(c for c in found if c not in set(known))
        self.newly_confirmed = new
        self._last = (k, looks, new, self.task, self.task_reward, inforce, safety.parents, taken)
        return command, outbox

    @property
    def last(self) -> StepDelta | None:
        """What the latest step changed (`StepDelta`; journals keep it), built when first asked for."""
        if isinstance(self._last, tuple):
            k, looks, new, task, reward, inforce, parents, taken = self._last
            triples, values = self._records_taken(k, taken)
            self._last = StepDelta(k, tuple(looks), new, task, reward, inforce, parents, triples, values)
        return self._last

    def _rank(
        self, pose: tuple[float, float, float], nxt: FloatArray, nbr_tracks: FloatArray
    ) -> tuple[IntArray, FloatArray]:
        """The paths of eq. 23 from `pose` (t_k+1, at `nxt`) in eq. 22's order, and their points.

        Scored (eqs. 24-25, 29) on eta, on s = eta Pr for no-ta, or on the pheromone field."""
        w, grid = self.world, self.world.grid
        x1, y1, h1 = pose
        if self.algorithm == "no-ta":
            np.multiply(self.eta, self._relative_prior, out=self._values[:-1])
        elif self.phi is not None:
            self.phi = phero.step_field(
                grid, self.phi, self.eta, w.prior, w.mission.algorithm.pheromone, self._values
            )
        tess = w.tessellation
        labels = self._labels
        if self.task >= 0 and tess is not None and self.task >= tess.n_tasks:
            c = self.task - tess.n_tasks  # a confirmation task: the FOV disc about its cell
            region: TaskRegion = (self.task, grid.centres[c], grid.fov_radius, STRAIGHT)
            labels = np.full_like(labels, -1)
            labels[grid.fov_table[c]] = self.task
            labels[-1] = -1
        elif self.task >= 0 and tess is not None:
            j = self.task
            region = (j, tess.generators[j], float(tess.circumradii[j]), tess.routes)
        else:
            region = (-1, nxt, 1.0, STRAIGHT)
        if w.kinematics.mode == "grid":
            return rank_grid_candidates(
                x1, y1, w.paths.offsets_from(h1), self._grid_cells, self._values, labels, region,
                nbr_tracks, self._weights,
            )  # fmt: skip
        pts = w.paths.expand(x1, y1, h1)
        cells, fov, prefix = continuous_path_cells(grid, w.kinematics, pts)
        labels = labels[cells] if region[0] >= 0 else cells  # cell -1 reads the trailing -1
        return rank_candidates(pts, fov, prefix, self._values, labels, region, nbr_tracks, self._weights), pts

    def _plan_of(
        self,
        k: int,
        pose: tuple[float, float, float],
        best: int,
        side: int,
        path: FloatArray,
        inforce: Trajectory,
        obs: Observation,
    ) -> tuple[Trajectory | None, Track, tuple[float, ...]]:
        """The proposal of path `best` (side `side`) from `pose`, and the plan (points, headings) announced.

        With no path allowed, or the mission closing, no proposal and the trajectory in force's track."""
        x1, y1, h1 = pose
        horizon, paths, known = self._horizon, self.world.paths, self._turns
        if best >= 0 and not obs.closing:
            turns = known.get(best) or known.setdefault(best, tuple(paths.sequences[best].tolist()))
            proposal = Trajectory(k + 1, x1, y1, h1, turns, side)
            plan: Track = ((x1, y1), *map(tuple, path[: horizon - 1].tolist()))
            return proposal, plan, (h1, *paths.headings_along(h1, best)[: horizon - 1])
        ahead = inforce.reanchored(k + 1, x1, y1, h1, self.commitments.limits.reach.loiter_turn)
        return None, *self.commitments.limits.track(ahead)

    def _outbox(
        self,
        obs: Observation,
        me: UavState,
        looked: tuple[tuple[int, ...], tuple[float, ...]],
        found: tuple[int, ...],
        announce: bool,
    ) -> list[Message]:
        """This step's messages: state, coverage (looks, evidence, records), relayed states and bids."""
        k, x, y, parents = obs.step, obs.x, obs.y, self.commitments.parents
        heard, relay = tuple(sorted(self.neighbours)), self._relay()
        self._heard = heard
        outbox: list[Message] = [
            StateMsg(sender=self.uav, stamp=k, x=x, y=y, state=me, heard=heard, parents=parents),
            self._coverage(obs, looked[0], looked[1], found),
        ]
        if relay:
            known = tuple(self.peers[u] for u in relay)
            outbox.append(ClaimsMsg(sender=self.uav, stamp=k, x=x, y=y, known=known))
        if announce:
            assert self.bids is not None
            rewards, cells, confirm = self.bids
            bid = BidsMsg(
                sender=self.uav,
                stamp=k,
                x=x,
                y=y,
                rewards=rewards,
                confirm=cells,
                confirm_rewards=confirm,
            )
            outbox.append(bid)
        return outbox

    def _coverage(
        self, obs: Observation, cells: tuple[int, ...], evidence: tuple[float, ...], found: tuple[int, ...]
    ) -> CoverageMsg:
        """Its looks with its evidence at them, every record at the cells of interest, the confirmed."""
        records, values = self.belief.records()
        return CoverageMsg(
            sender=self.uav, stamp=obs.step, x=obs.x, y=obs.y, cells=cells, detections=found,
            evidence=evidence, records=records, record_values=values,
        )  # fmt: skip

    # -- snapshot and restore ------------------------------------------------------------------
    def snapshot(self) -> AgentSnapshot:
        """This agent's own knowledge after its latest step (`AgentSnapshot`)."""
        c = self.commitments
        step = self.last.step if self.last is not None else -1
        phi = None if self.phi is None else self.phi.astype("<f8").tobytes()
        return AgentSnapshot(
            self.uav, step, self.eta.astype("<f8").tobytes(), np.packbits(self.seen).tobytes(),
            tuple(sorted(self.found)), self.task, self.task_reward, c.inforce, c.parents, phi,
            *self.belief.to_bytes(),
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
        self.belief.restore(snap.evidence, snap.evidence_stamps)
        self._settle()
        self._restart(snap.step, snap.task, snap.task_reward, snap.inforce, snap.parents)

    def replay(self, delta: StepDelta) -> None:
        """Apply a later step's delta to a restored agent, exactly as the step changed it."""
        self._update_map(np.array(delta.looks, dtype=np.int64))
        records = np.array(delta.records, dtype=np.int64).reshape(-1, 3)
        self.belief.merge(records, np.array(delta.record_values, dtype=float), own=True)
        self._settle()
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
        self._last = StepDelta(step, (), (), task, reward, inforce, tuple(parents))
