"""Recovery after a fault left two UAVs' trajectories in force within R_s of each other (a radio
partition at close range: each side flew on as if the other were gone): the safety layer lets a
pair already too close take only plans that keep at least the clearance their trajectories in
force have (`safety.keeps_apart`), prefers the plan that opens it fastest, and so gets the pair
apart again and keeps it apart, instead of holding both UAVs on parallel trajectories and loiters
that keep the violation forever."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.batch.engine import Radio, initial_poses
from companion.core.agent import Agent, Observation
from companion.core.feasibility import load_mission
from companion.core.trajectory import Trajectory
from companion.core.world import Stream, build_world, instance_rng

ROOT = Path(__file__).resolve().parents[2]
RECOVER_STEPS = 20  # generous: at most 6 steps measured (2 missions x 15 seeds x 3 steps)


def _fly_with_a_fault(name: str, seed: int, at: int, steps: int) -> tuple[np.ndarray, float]:
    """The swarm over a radio; at step `at` UAV 1 is found one cell west of UAV 2, committed to UAV 2's
    trajectory in force moved there (what a partition can leave). Returns the UAV 1-2 distances at
    every step from `at` on, and R_s + buffer."""
    m = load_mission(ROOT / "mission_files" / f"{name}.toml")
    world = build_world(m, seed, 0)
    agents = [Agent(world, i) for i in range(m.n_uavs)]
    radio = Radio(m.comms.range, 0.0, instance_rng(seed, 0, Stream.RADIO), wire=False)
    poses = initial_poses(m)
    inboxes: list[list] = [[] for _ in agents]
    distances = []
    for k in range(steps):
        if k == at:
            gap = m.region.cell_size
            t = agents[2].commitments.inforce
            agents[1].commitments.inforce = Trajectory(t.start, t.x - gap, t.y, t.heading, t.turns, t.loiter)
            agents[1].commitments.proposal = None
            poses[1] = poses[2] - (gap, 0.0, 0.0)
        turns, outboxes = np.empty(len(agents)), []
        for i, agent in enumerate(agents):
            x, y, h = poses[i].tolist()
            command, outbox = agent.step(Observation(step=k, x=x, y=y, heading=h), inboxes[i])
            turns[i] = command.turn
            outboxes.append(outbox)
        if k >= at:
            distances.append(float(np.hypot(*(poses[1, :2] - poses[2, :2]))))
        inboxes = radio.deliver(poses[:, :2], outboxes)
        poses = world.kinematics.advance_poses(poses, turns)
    return np.array(distances), m.comms.safety + m.safety.buffer


@pytest.mark.parametrize("name", ["scenario1", "scenario1_continuous"])
@settings(max_examples=5, deadline=None)
@given(seed=st.integers(0, 10_000), at=st.integers(5, 60))
def test_a_pair_within_r_s_gets_apart_and_stays_apart(name: str, seed: int, at: int) -> None:
    d, apart = _fly_with_a_fault(name, seed, at, at + 80)
    out = np.flatnonzero(d > apart)
    assert out.size and out[0] <= RECOVER_STEPS, f"still {d[: RECOVER_STEPS + 1].max():.0f} m apart at most"
    assert (d[out[0] :] > apart).all(), f"closed in again to {d[out[0] :].min():.1f} m"
