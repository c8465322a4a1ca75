"""The per-UAV Agent: track prediction, message hygiene, and what it does with its inbox."""

from __future__ import annotations

import msgspec
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from companion.batch.engine import Radio, initial_poses
from companion.core.agent import Agent, Observation
from companion.core.connectivity import pairwise_distances
from companion.core.messages import BidsMsg, ClaimsMsg, Message, StateMsg, check, decode, encode
from companion.core.swarm_view import predict_tracks
from companion.core.world import build_world


def test_predict_tracks_follows_the_plan_then_extrapolates() -> None:
    # UAV at (0, 0) at stamp 5 with plan (10, 0), (20, 0): steps 5..9 -> 0, 10, 20, then the last
    # planned velocity (10, 0) per step: 30, 40. Asked from step 4 (before its stamp): one step back, -10.
    seqs = np.array([[[0.0, 0.0], [10.0, 0.0], [20.0, 0.0]]])
    out = predict_tracks(seqs, np.array([5]), 5, 5)
    assert out[0, :, 0].tolist() == [0.0, 10.0, 20.0, 30.0, 40.0]
    assert np.all(out[0, :, 1] == 0.0)
    assert predict_tracks(seqs, np.array([5]), 4, 1)[0, 0].tolist() == [-10.0, 0.0]


def run_agents(mission, steps: int, seed: int = 1):
    """Drive the agents by hand (all-to-all radio within R_c, one step of latency) and yield per step."""
    world = build_world(mission, seed, 0)
    agents = [Agent(world, i) for i in range(mission.n_uavs)]
    poses = initial_poses(mission)
    inboxes: list[list[Message]] = [[] for _ in agents]
    for k in range(steps):
        outs = [
            a.step(Observation(step=k, x=p[0], y=p[1], heading=p[2]), inboxes[i])
            for i, (a, p) in enumerate(zip(agents, poses.tolist(), strict=True))
        ]
        yield k, world, agents, outs
        near = pairwise_distances(poses[:, :2]) <= mission.comms.range
        inboxes = [
            [decode(encode(m)) for j, (_, out) in enumerate(outs) if j != i and near[i, j] for m in out]
            for i in range(len(agents))
        ]
        turns = np.array([c.turn for c, _ in outs])
        x, y, h = world.kinematics.advance(poses[:, 0], poses[:, 1], poses[:, 2], turns)
        poses = np.column_stack([x, y, h])


def test_agents_emit_only_well_formed_messages_and_admissible_commands(scenario1) -> None:
    opts = None
    for k, world, _agents, outs in run_agents(scenario1, 25):
        opts = world.kinematics.turn_options
        tess = world.tessellation
        assert tess is not None
        for i, (cmd, out) in enumerate(outs):
            assert cmd.step == k
            assert np.any(np.isclose(cmd.turn, opts))  # |turn| <= omega_max, one of the options
            assert len(cmd.path) == scenario1.algorithm.horizon
            assert -1 <= cmd.task < tess.n_tasks
            assert isinstance(out[0], StateMsg) and out[0].state.task == cmd.task
            for msg in out:
                assert msg.sender == i and msg.stamp == k
                check(msg, scenario1.n_uavs, world.grid.n_cells, tess.n_tasks)
    assert opts is not None


def test_first_step_bids_then_auction(scenario1) -> None:
    gen = run_agents(scenario1, 2)
    _, world, _, outs = next(gen)
    # step 0: nobody holds a task; every UAV announces one positive bid per task
    for cmd, out in outs:
        assert cmd.task == -1
        bids = [m for m in out if isinstance(m, BidsMsg)]
        assert len(bids) == 1 and len(bids[0].rewards) == world.tessellation.n_tasks
        assert max(bids[0].rewards) > 0
    # step 1: each takes a task from the same auction; the start line is within R_c for all, so
    # everyone hears everyone and there is no conflict
    _, _, _, outs = next(gen)
    tasks = [cmd.task for cmd, _ in outs]
    assert all(t >= 0 for t in tasks) and len(set(tasks)) == len(tasks)


def test_a_task_holder_is_a_greedy_bidder(scenario1) -> None:
    """Algorithm 2: UAVs holding a task bid too, only for tasks worth more than the one they hold,
    and take a better task they win. Here UAV 0's task is made worthless (its cells seen, not yet
    counted as covered): it bids for others and switches."""
    gen = run_agents(scenario1, 6)
    for k, world, agents, outs in gen:
        if k == 2:
            held = agents[0].task
            assert held >= 0
            agents[0].eta[world.tessellation.labels == held] = 1e-6
        if k == 3:  # the bids of step 3: zero for the held task, positive for others
            bids = next(m for m in outs[0][1] if isinstance(m, BidsMsg))
            assert bids.rewards[held] == 0.0 and max(bids.rewards) > 0
        if k == 4:  # the auction of step 4 gave it another task
            assert outs[0][0].task not in (-1, held)


def test_eq_21_ends_and_refuses_tasks_beyond_a_neighbours_range(scenario1) -> None:
    """Eq. 21 with eq. 17 uncapped: a UAV neither bids for a task whose generator is beyond R_c of
    an MST neighbour nor keeps one it was given (UAV 0 at the start line's west end, UAV 1 400 m east)."""
    r_c = scenario1.comms.range
    far = None
    for k, world, agents, outs in run_agents(scenario1, 4):
        if k == 1:
            gens = world.tessellation.generators
            me, uav1 = (np.array(outs[i][1][0].state.plan[0]) for i in (0, 1))  # both next poses
            beyond = np.hypot(*(gens - uav1).T) > r_c
            agents[0].task = -1  # bids as a UAV without a task: every task it could keep
            bids = np.array(agents[0]._my_bids(me, uav1[None, :])[0])  # the CVT tasks
            assert beyond.any() and (bids[~beyond] > 0).any()
            assert np.all(bids[beyond] == 0.0)
            far = int(np.flatnonzero(beyond)[0])
            agents[0].task, agents[0].task_reward = far, 1e9  # given a far task by hand
        if k == 2:  # reevaluated at step 2 (its cost is above any C_max): dropped, not won back
            assert far is not None and outs[0][0].task != far


def test_agent_eta_never_rises_and_agents_share_no_state(scenario1) -> None:
    prev = None
    for _, _, agents, _ in run_agents(scenario1, 15):
        etas = np.array([a.eta for a in agents])
        assert np.all((etas >= 0) & (etas <= scenario1.uncertainty.eta0))
        if prev is not None:
            assert np.all(etas <= prev)
        prev = etas.copy()
        assert len({id(a.eta) for a in agents}) == len(agents)
    # each UAV's own look: eta of the cell under it is at most gamma (seen at least once)
    a0 = agents[0]
    assert a0.eta.min() <= scenario1.uncertainty.gamma + 1e-12


def test_stale_and_own_messages_are_rejected(scenario1) -> None:
    world = build_world(scenario1, 1, 0)
    agent = Agent(world, 0)
    p = initial_poses(scenario1)[0]
    _, out = agent.step(Observation(step=0, x=p[0], y=p[1], heading=p[2]), [])
    timeout = scenario1.comms.peer_timeout_steps
    obs = Observation(step=timeout + 1, x=p[0], y=p[1], heading=p[2])
    agent.step(obs, out)  # its own messages, and too old: all rejected
    assert agent.rejected == len(out)
    assert agent.peers == {}


@pytest.mark.parametrize("algorithm", ["no-ta", "pheromone"])
def test_baselines_never_take_tasks(scenario1, algorithm: str) -> None:
    for _, _, _, outs in run_agents(scenario1.with_algorithm(algorithm), 5):
        for cmd, out in outs:
            assert cmd.task == -1
            assert not any(isinstance(m, BidsMsg) for m in out)


def test_no_ta_scores_importance_on_etas_scale(scenario1) -> None:
    """no-ta's search term is s = eta Pr (eq. 12) relative to the prior's peak: on eta's scale, as
    the proposed method's eta is, so eq. 22 weighs both against eq. 29's barriers alike."""
    for _, world, agents, _ in run_agents(scenario1.with_algorithm("no-ta"), 2):
        values = agents[0]._values[:-1]
        s = agents[0].eta * world.prior
        assert values == pytest.approx(s / world.prior.max())
        assert values.max() == pytest.approx(scenario1.uncertainty.eta0)  # the peak cell is not seen yet


def _hops(near: np.ndarray) -> np.ndarray:
    """Hop distance between every pair of the range graph `near` (-1: not connected)."""
    n = len(near)
    hops = np.full((n, n), -1)
    for s in range(n):
        hops[s, s], frontier, d = 0, [s], 0
        while frontier:
            d += 1
            frontier = [v for u in frontier for v in np.flatnonzero(near[u]) if hops[s, v] < 0]
            for v in frontier:
                hops[s, v] = d
    return hops


def _static_swarm(scenario1, points: list[tuple[float, float]], steps: int):
    """Agents of UAVs held at `points` (the observation never moves) exchanging messages over
    the batch engine's radio for `steps` steps; yields (k, agents, outboxes) after each step."""
    vehicles = [msgspec.structs.replace(scenario1.vehicles[0], x=x, y=y) for x, y in points]
    mission = msgspec.structs.replace(scenario1, vehicles=vehicles).with_algorithm("no-ta")
    world = build_world(mission, 1, 0)
    agents = [Agent(world, i) for i in range(len(points))]
    positions = np.array(points, dtype=float)
    radio = Radio(mission.comms.range, 0.0, np.random.default_rng(0), wire=True)
    inboxes: list[list[Message]] = [[] for _ in agents]
    for k in range(steps):
        outs = [
            a.step(Observation(step=k, x=x, y=y, heading=0.0), inboxes[i])
            for i, (a, (x, y)) in enumerate(zip(agents, points, strict=True))
        ]
        yield k, agents, [out for _, out in outs]
        inboxes = radio.deliver(positions, [out for _, out in outs])


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.lists(st.tuples(st.integers(-12, 12), st.integers(-12, 12)), min_size=2, max_size=9, unique=True))
def test_relays_bring_every_state_one_step_per_hop(scenario1, cells: list[tuple[int, int]]) -> None:
    """Multi-hop dissemination: with relays only where a neighbour did not hear a peer itself, UAV
    i still knows UAV j's state of step k - hops(i, j) after step k, as a full flood would."""
    points = [(80.0 * cx + 20.0, 80.0 * cy + 20.0) for cx, cy in cells]  # two cells apart, beyond R_s
    near = pairwise_distances(np.array(points)) <= scenario1.comms.range
    hops = _hops(near)
    steps = int(hops.max()) + 4  # reports of whom each heard settle after two steps
    for k, agents, _ in _static_swarm(scenario1, points, steps):
        if k < 2 + hops.max():
            continue
        for i, a in enumerate(agents):
            for j in range(len(agents)):
                if i != j and hops[i, j] > 0:
                    assert a.peers[j].stamp == k - hops[i, j], (i, j, hops[i, j])
                elif i != j:
                    assert j not in a.peers


def test_a_swarm_where_everyone_hears_everyone_relays_nothing(scenario1) -> None:
    points = [(20.0 + 200.0 * i, 20.0) for i in range(4)]  # 600 m across, R_c 1000 m
    for k, _, outs in _static_swarm(scenario1, points, 6):
        relays = [m for out in outs for m in out if isinstance(m, ClaimsMsg)]
        assert k < 2 or not relays  # before the first reports of whom each heard, all relay


def test_a_chain_relays_through_its_middle(scenario1) -> None:
    r = scenario1.comms.range
    points = [(20.0 - 0.9 * r, 20.0), (20.0, 20.0), (20.0 + 0.9 * r, 20.0)]  # 0 - 1 - 2
    *_, (k, agents, outs) = _static_swarm(scenario1, points, 6)
    relays = {
        i: [s.uav for m in out if isinstance(m, ClaimsMsg) for s in m.known] for i, out in enumerate(outs)
    }
    assert relays == {0: [], 1: [0, 2], 2: []}
    assert agents[0].peers[2].stamp == k - 2 and agents[2].peers[0].stamp == k - 2
