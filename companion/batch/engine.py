"""Batch engine: N agents in one process, a range-gated simulated radio, kinematics and ground truth.

`simulate` is a pure function of (mission, seed, run index, steps): run r of seed s is always the
same mission instance (CVT, targets, radio losses), whatever else is in a batch.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np
from numba import njit

from companion.batch.dead_vehicle import DeadVehicle
from companion.contracts.mission import Mission
from companion.core.agent import Agent, Observation
from companion.core.connectivity import algebraic_connectivity, min_pair_distance, pairwise_distances
from companion.core.geometry import IntArray
from companion.core.messages import Message, decode, encode
from companion.core.prior import draw_targets
from companion.core.search_area import keepout_entries, keepout_pieces
from companion.core.sensing import reported_cells
from companion.core.trajectory import segment_clearance, step_pose
from companion.core.uncertainty import global_average_uncertainty, mark_seen
from companion.core.world import Stream, World, build_world, instance_rng


@dataclass
class RunResult:
    """Per-step metrics of one run (arrays of length `steps`) and the first-seen step of each target."""

    algorithm: str
    run: int
    seed: int
    steps: int
    uncertainty: np.ndarray  # eq. 30
    found: np.ndarray
    coverage: np.ndarray
    lambda2: np.ndarray
    min_distance: np.ndarray
    # closest approach during [t_k, t_k+1] (between sampling moments) of any pair that can meet: two
    # live UAVs whatever their layers, or a dead or unsteered one and another on a near layer
    approach: np.ndarray
    separation_losses: int  # steps during which such a pair came within R_s (closest approach)
    link_losses: int  # sampling moments at which the communication graph was split (lambda_2 = 0)
    target_cells: np.ndarray
    target_steps: np.ndarray  # -1 = never seen
    seconds: float
    trajectory: np.ndarray | None = None  # (steps, N, 3): x, y, heading
    tasks: np.ndarray | None = None  # (steps, N) task held after each step (-1 none)
    rejected_messages: int = 0
    # chords between consecutive sampling points, per UAV, entering a no-fly zone inflated by
    # safety.margin or leaving a non-convex region's margin (`search_area.keepout_pieces`); None
    # for a convex region without zones
    keepout_entries: int | None = None
    # what an imperfect sensor's confirmations did (`Sensing`); None for a perfect sensor, whose
    # first look confirms (`confirm_steps` is then `target_steps`)
    sensing: Sensing | None = None
    extras: dict = field(default_factory=dict)

    def target_times(self) -> np.ndarray:
        """First-seen step of each target, an unfound target counting as `steps`."""
        return np.where(self.target_steps >= 0, self.target_steps, self.steps)

    @property
    def confirm_steps(self) -> np.ndarray:
        """The step at which some UAV first confirmed each target (-1 never)."""
        return self.target_steps if self.sensing is None else self.sensing.confirm_steps

    @property
    def false_confirmations(self) -> int:
        """Cells holding no target that some UAV confirmed."""
        return 0 if self.sensing is None else int(self.sensing.false_cells.shape[0])

    def confirm_times(self) -> np.ndarray:
        """First confirmation step of each target, one never confirmed counting as `steps`."""
        return np.where(self.confirm_steps >= 0, self.confirm_steps, self.steps)


@dataclass
class Sensing:
    """The confirmations of a run with an imperfect sensor (docs/algorithm.md, "Imperfect sensing").

    `confirm_steps`: per target (as `target_cells`), the step some UAV first held it confirmed (-1
    never); `false_cells`/`false_steps`: the cells holding no target that some UAV confirmed, and
    when first; `reports`/`false_reports`: the detector's reports, and those of empty cells."""

    confirm_steps: np.ndarray
    false_cells: np.ndarray
    false_steps: np.ndarray
    reports: int
    false_reports: int


@njit(cache=True)
def _ground_truth(
    k: int,
    positions: np.ndarray,
    target_xy: np.ndarray,
    radius2: float,
    first: np.ndarray,
    covered: np.ndarray,
    fov_cells: np.ndarray,
    comm_range: float,
) -> tuple[np.ndarray, int, int, float, float]:
    """One step of `Scorer.record`, compiled.

    One step of `Scorer.record`: (UAV, target) pairs in view, targets found so far (first-seen
    steps updated in place), cells looked at for the first time, lambda_2 and the minimum distance."""
    n, n_targets = positions.shape[0], target_xy.shape[0]
    sees = np.zeros((n, n_targets), dtype=np.bool_)
    found = 0
    for t in range(n_targets):
        for i in range(n):
            dx, dy = positions[i, 0] - target_xy[t, 0], positions[i, 1] - target_xy[t, 1]
            sees[i, t] = dx * dx + dy * dy <= radius2
            if sees[i, t] and first[t] < 0:
                first[t] = k
        found += first[t] >= 0
    no_tasks = np.zeros(0, dtype=np.int64)  # mark_seen without per-task counts
    new = mark_seen(covered, no_tasks, no_tasks, fov_cells.ravel())
    return sees, found, new, algebraic_connectivity(positions, comm_range), min_pair_distance(positions)


APPROACH_SUBSTEPS = 8


@njit(cache=True)
def closest_approach(
    poses: np.ndarray,
    turns: np.ndarray,
    grid: bool,
    speed: float,
    dt: float,
    cell: float,
    substeps: int,
    pairs: np.ndarray,
) -> float:
    """The closest approach over one step of the pairs marked in `pairs` (eq. 2 flights).

    min over the pairs marked in `pairs` (n, n) of the horizontal distance between two UAVs
    flying eq. 2 from `poses` with `turns` over one step: grid UAVs fly straight between cell centres
    (exact); continuous UAVs fly arcs, sampled at `substeps` points with straight motion between
    them (within the sagitta of 1/substeps of a turn)."""
    n = poses.shape[0]
    tracks = np.empty((n, substeps + 1, 2))
    for i in range(n):
        x, y, h = poses[i, 0], poses[i, 1], poses[i, 2]
        tracks[i, 0, 0], tracks[i, 0, 1] = x, y
        for j in range(1, substeps + 1):
            f = j / substeps
            tracks[i, j, 0], tracks[i, j, 1], _ = step_pose(x, y, h, turns[i] * f, grid, speed, dt * f, cell)
    best = math.inf
    for i in range(n):
        for j in range(i + 1, n):
            if pairs[i, j]:
                best = min(best, segment_clearance(tracks[i], tracks[j]))
    return best


class Scorer:
    """Ground-truth metrics of one run, step by step.

    Ground-truth metrics of one run, step by step (a target is found when its cell centre is
    within R_A of some UAV): targets found, coverage, lambda_2 and the minimum pairwise distance,
    with the uncertainty of eq. 30 handed in. The batch engine and the flown-mission evaluator
    both score with it."""

    def __init__(self, world: World, targets: np.ndarray, steps: int) -> None:
        self.world, self.targets = world, targets
        self.target_xy = world.grid.centres[targets]
        self.first = np.full(len(targets), -1)
        self.covered = np.zeros(world.grid.n_cells, dtype=bool)
        self.n_covered = 0
        self.unc, self.found, self.cov, self.lam, self.mind = (np.zeros(steps) for _ in range(5))
        self.approach = np.full(steps, np.inf)
        m = world.mission
        self.keepout = keepout_pieces(m, world.grid.region, m.safety.margin, m.safety.margin)
        self.entries = 0
        self._before: np.ndarray | None = None
        self.holds_target = np.zeros(world.grid.n_cells, dtype=bool)
        self.holds_target[targets] = True
        self.confirmed: dict[int, int] = {}  # cell -> step some UAV first held it confirmed
        self.reports = self.false_reports = 0
        self._pairs: dict[tuple, np.ndarray] = {}  # `record_flight`'s pairs, by which UAVs are live

    def confirm(self, k: int, cells: tuple[int, ...]) -> None:
        """Cells a UAV's map confirmed at step k."""
        for c in cells:
            self.confirmed.setdefault(c, k)

    def reported(self, cells: IntArray) -> None:
        """Cells the detector reported at one look (imperfect sensors: `Sensing.reports`)."""
        self.reports += cells.shape[0]
        self.false_reports += int(np.count_nonzero(~self.holds_target[cells]))

    def record(self, k: int, positions: np.ndarray, uncertainty: float = math.nan) -> np.ndarray:
        """Score the UAVs at `positions` at step k; returns which UAV sees which target (eq. 3).

        Score the UAVs at `positions` at step k; returns which UAV sees which target (eq. 3).
        The uncertainty of step k may be handed in later (`unc[k]`)."""
        m, grid = self.world.mission, self.world.grid
        sees, found, new, lam, mind = _ground_truth(
            k,
            positions,
            self.target_xy,
            grid.fov_radius2,
            self.first,
            self.covered,
            grid.fov_cells(positions),
            m.comms.range,
        )
        self.n_covered += new
        if self.keepout.shape[0]:
            if self._before is not None:
                self.entries += keepout_entries(self._before, positions, self.keepout)
            self._before = np.array(positions[:, :2], dtype=float)
        self.found[k], self.lam[k], self.mind[k] = found, lam, mind
        self.cov[k] = self.n_covered / grid.n_cells
        self.unc[k] = uncertainty
        return sees

    def record_flight(self, k: int, poses: np.ndarray, turns: np.ndarray, live: np.ndarray) -> None:
        """The closest approach over [t_k, t_k+1] of the pairs that can meet.

        The closest approach while flying the turns from `poses` over [t_k, t_k+1] of the pairs
        that can meet: both `live` (steered by a live companion), or on near layers (an aircraft
        nobody steers holds its layer, so only those on layers closer than the vertical separation
        can meet it)."""
        kin = self.world.kinematics
        grid = kin.mode == "grid"
        substeps = 1 if grid else APPROACH_SUBSTEPS
        key = tuple(live.tolist())
        pairs = self._pairs.get(key)
        if pairs is None:
            pairs = self._pairs[key] = self.world.safety.near | np.logical_and.outer(live, live)
        self.approach[k] = closest_approach(
            poses, turns, grid, kin.speed, kin.dt, kin.cell_size, substeps, pairs
        )

    def result(self, run: int, seed: int, seconds: float, **extra: object) -> RunResult:
        """The run's `RunResult`, with `extra` fields."""
        steps = len(self.unc)
        m = self.world.mission
        sensing = None
        if not self.world.sensor.perfect:
            steps_of = self.confirmed.get
            false = sorted(c for c in self.confirmed if not self.holds_target[c])
            sensing = Sensing(
                np.array([steps_of(int(c), -1) for c in self.targets], dtype=np.int64),
                np.array(false, dtype=np.int64),
                np.array([self.confirmed[c] for c in false], dtype=np.int64),
                self.reports,
                self.false_reports,
            )
        return RunResult(
            algorithm=self.world.mission.algorithm.name,
            run=run,
            seed=seed,
            steps=steps,
            uncertainty=self.unc,
            found=self.found,
            coverage=self.cov,
            lambda2=self.lam,
            min_distance=self.mind,
            approach=self.approach,
            separation_losses=int(np.count_nonzero(self.approach <= m.comms.safety)),
            link_losses=int(np.count_nonzero(self.lam <= 0)) if m.n_uavs > 1 else 0,
            keepout_entries=self.entries if self.keepout.shape[0] else None,
            sensing=sensing,
            target_cells=self.targets,
            target_steps=self.first,
            seconds=seconds,
            **extra,  # type: ignore[arg-type]
        )


class Radio:
    """Delivers each message to every other UAV within R_c of the sender, with optional loss."""

    def __init__(self, comm_range: float, loss: float, rng: np.random.Generator, wire: bool) -> None:
        self.comm_range, self.loss, self.rng, self.wire = comm_range, loss, rng, wire

    def deliver(self, positions: np.ndarray, outboxes: list[list[Message]]) -> list[list[Message]]:
        """Each receiver's inbox: the in-range senders' messages, by sender id then outbox order."""
        n = len(outboxes)
        in_range = (pairwise_distances(positions) <= self.comm_range).tolist()
        if self.wire:
            outboxes = [[decode(encode(msg)) for msg in outbox] for outbox in outboxes]
        if self.loss == 0:
            return [[m for i in range(n) if i != j and in_range[i][j] for m in outboxes[i]] for j in range(n)]
        inboxes: list[list[Message]] = [[] for _ in range(n)]
        for i, outbox in enumerate(outboxes):  # loss draws in (sender, message, receiver) order
            for msg in outbox:
                for j in range(n):
                    if j != i and in_range[i][j] and self.rng.random() >= self.loss:
                        inboxes[j].append(msg)
        return inboxes


def initial_poses(mission: Mission) -> np.ndarray:
    """The vehicles' start poses (x, y, heading in radians), a row each."""
    return np.array([(v.x, v.y, math.radians(v.heading_deg)) for v in mission.vehicles], dtype=float)


@dataclass
class Faults:
    """The companions that die or stop steering in a run, and the dead ones' vehicles.

    The companions that die (`kills`: UAV -> step) and stop steering (`takeovers`: UAV -> step)
    in a run of `steps` steps, and the vehicles of the dead ones (`DeadVehicle`)."""

    death: dict[int, int]
    held: dict[int, int]
    steps: int
    dead: dict[int, DeadVehicle] = field(default_factory=dict)

    def dead_at(self, uav: int, k: int) -> bool:
        """Whether `uav`'s companion is dead at step k."""
        return self.death.get(uav, self.steps) <= k

    def steered_at(self, uav: int, k: int) -> bool:
        """Whether `uav`'s companion steers its vehicle at step k."""
        return self.held.get(uav, self.steps) > k


def simulate(
    mission: Mission,
    seed: int,
    run: int = 0,
    steps: int | None = None,
    record: bool = False,
    wire: bool = False,
    world: World | None = None,
    kills: Mapping[int, int] | None = None,
    takeovers: Mapping[int, int] | None = None,
    probe: Callable[[int, list[Agent]], None] | None = None,
) -> RunResult:
    """One Monte Carlo run of `mission.algorithm` for `steps` sampling moments.

    `wire=True` sends every message through its msgpack encoding, as the mesh does. `kills` maps
    a UAV to the step at which its companion dies: from then on it sends nothing and its vehicle
    holds its last turn until its failsafe fires, then flies onto its failsafe loiter and circles
    it (`DeadVehicle`). `takeovers` maps a UAV to the step from which its companion no longer
    steers its vehicle (a pilot took over, the autopilot fell back to Hold): the vehicle circles
    where it is, turning at the loiter turn, and its agent, told so (`Observation.steered`), goes
    on publishing its position and commits to nothing. `probe(k, agents)`, if given, is called
    once every agent has taken step k (tests read the agents' commitments there).
    """
    started = time.perf_counter()
    steps = mission.steps if steps is None else steps
    world = world or build_world(mission, seed, run)
    n = mission.n_uavs
    agents = [Agent(world, i) for i in range(n)]
    targets = draw_targets(world.prior, mission.prior.targets, instance_rng(seed, run, Stream.TARGETS))
    radio = Radio(mission.comms.range, mission.comms.loss, instance_rng(seed, run, Stream.RADIO), wire)
    scorer = Scorer(world, targets, steps)
    poses = initial_poses(mission)
    traj = np.zeros((steps, n, 3)) if record else None
    tasks = np.full((steps, n), -1, dtype=np.int64) if record else None
    inboxes: list[list[Message]] = [[] for _ in range(n)]
    faults = Faults(
        {i: d for i, d in (kills or {}).items() if 0 <= i < n},
        {i: d for i, d in (takeovers or {}).items() if 0 <= i < n},
        steps,
    )
    last = np.zeros(n)  # each vehicle's latest turn: the command a dead companion leaves held
    everyone = np.ones(n, dtype=bool)  # `live` of a run without faults
    for k in range(steps):
        sees = scorer.record(k, poses[:, :2])
        stepped = _step_agents(k, agents, world, faults, poses, last, sees, scorer, (seed, run), inboxes)
        turns, outboxes, commanded = stepped
        if tasks is not None:
            tasks[k] = commanded
        if probe is not None:
            probe(k, agents)
        scorer.unc[k] = global_average_uncertainty([a.eta for a in agents])
        if traj is not None:
            traj[k] = poses
        inboxes = radio.deliver(poses[:, :2], outboxes)
        live = everyone
        if faults.death or faults.held:
            live = np.array([not faults.dead_at(i, k) and faults.steered_at(i, k) for i in range(n)])
        scorer.record_flight(k, poses, turns, live)
        last = turns
        poses = world.kinematics.advance_poses(poses, turns)
    return scorer.result(
        run,
        seed,
        time.perf_counter() - started,
        trajectory=traj,
        tasks=tasks,
        rejected_messages=sum(a.rejected for a in agents),
        extras={
            "proposals_accepted": sum(a.commitments.accepted for a in agents),
            "proposals_rejected": sum(a.commitments.rejected for a in agents),
            "recovered": sum(a.commitments.recovered for a in agents),
            "first_choices": sum(a.commitments.first_asked for a in agents),
            "first_choices_refused": sum(a.commitments.first_refused for a in agents),
        },
    )


def _step_agents(
    k: int,
    agents: list[Agent],
    world: World,
    faults: Faults,
    poses: np.ndarray,
    last: np.ndarray,
    sees: np.ndarray,
    scorer: Scorer,
    instance: tuple[int, int],
    inboxes: list[list[Message]],
) -> tuple[np.ndarray, list[list[Message]], list[int]]:
    """Step k of every UAV: the turns flown, the outboxes and each agent's task.

    Step k of every UAV from `poses`, each agent with its inbox and what its camera reports: the
    targets it `sees` (a perfect sensor), or `reported_cells`' draws for run `instance`
    (seed, run); the scorer learns the reports and each agent's confirmations. The turns flown
    over [t_k, t_k+1] (a dead companion's vehicle flies its `DeadVehicle` from its `last` turn; an
    unsteered one the loiter turn), the outboxes (empty for the dead) and each agent's task (-1 for
    the dead)."""
    n = len(agents)
    turns, commanded = np.empty(n), [-1] * n
    outboxes: list[list[Message]] = []
    loiter_turn = world.safety.limits.reach.loiter_turn
    perfect = world.sensor.perfect
    seen: list[bool] = np.logical_or.reduce(sees, axis=1).tolist() if perfect else []
    faulty = bool(faults.death or faults.held)
    for i, ((x, y, h), agent) in enumerate(zip(poses.tolist(), agents, strict=True)):
        if faulty and faults.dead_at(i, k):
            if i not in faults.dead:
                faults.dead[i] = DeadVehicle.of(world, k, float(last[i]), agent.commitments.inforce)
            turns[i] = faults.dead[i].turn(k, x, y, h)
            outboxes.append([])
            continue
        if perfect:
            detections = tuple(map(tuple, scorer.target_xy[sees[i]].tolist())) if seen[i] else ()
        else:
            grid = world.grid
            cells = grid.fov_cell_list((x, y))
            look = (*instance, i, k)
            reported = reported_cells(grid.centres, cells, scorer.holds_target, world.sensor, look, (x, y))
            detections = tuple(map(tuple, grid.centres[reported].tolist())) if reported.size else ()
            if detections:
                scorer.reported(reported)
        steered = not faulty or faults.steered_at(i, k)
        obs = Observation(step=k, x=x, y=y, heading=h, detections=detections, steered=steered)
        command, outbox = agent.step(obs, inboxes[i])
        if agent.newly_confirmed:
            scorer.confirm(k, agent.newly_confirmed)
        turns[i] = command.turn if steered else loiter_turn
        outboxes.append(outbox)
        commanded[i] = command.task
    return turns, outboxes, commanded
