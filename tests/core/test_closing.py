"""The mission's end (`Observation.closing`): every UAV flies out its trajectory in force and, after
horizon + 1 steps, is in its loiter; flown on forever, those loiters keep the swarm separated, at
equal times and, by the safety layer's contingency clause, at any phases and at the wider radius
ArduPlane flies them, between UAVs on near layers (those a layer apart are apart vertically:
docs/algorithm.md, "Separation in three dimensions"). This is what the companion's hand-over
(`flyout.fly_out`, `failsafe.hand_over`) relies on."""

from __future__ import annotations

from pathlib import Path

import msgspec
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.batch.engine import Radio, initial_poses
from companion.contracts.mission import Layers
from companion.core.agent import Agent, Observation
from companion.core.feasibility import load_mission
from companion.core.messages import StateMsg
from companion.core.safety.expansion import expand_with_centres
from companion.core.world import FAILSAFE_WIDE, Stream, build_world, instance_rng

ROOT = Path(__file__).resolve().parents[2]
MISSIONS = {
    f"{name}{suffix}": msgspec.structs.replace(mission, layers=Layers(count=count)) if count else mission
    for name in ("scenario1", "scenario1_continuous")
    for mission in [load_mission(ROOT / "mission_files" / f"{name}.toml")]
    for suffix, count in (("", None), ("_one_layer", 1))
}


def _fly_then_close(name: str, seed: int, open_steps: int, close_after: int | None = None):
    """The swarm over a radio, `open_steps` steps of search, then closing steps: horizon + 1 of
    them, or up to step `close_after` (whichever comes first)."""
    m = MISSIONS[name]
    world = build_world(m, seed, 0)
    agents = [Agent(world, i) for i in range(m.n_uavs)]
    radio = Radio(m.comms.range, 0.0, instance_rng(seed, 0, Stream.RADIO), wire=False)
    poses = initial_poses(m)
    inboxes: list[list] = [[] for _ in agents]
    closing_proposals = 0
    end = open_steps + m.algorithm.horizon + 1
    for k in range(end if close_after is None else min(end, close_after)):
        closing = k >= open_steps
        turns, outboxes = np.empty(len(agents)), []
        for i, agent in enumerate(agents):
            x, y, h = poses[i].tolist()
            command, outbox = agent.step(
                Observation(step=k, x=x, y=y, heading=h, closing=closing), inboxes[i]
            )
            turns[i] = command.turn
            outboxes.append(outbox)
            if closing:
                closing_proposals += sum(
                    isinstance(msg, StateMsg) and msg.state.proposal is not None for msg in outbox
                )
        inboxes = radio.deliver(poses[:, :2], outboxes)
        poses = world.kinematics.advance_poses(poses, turns)
    return world, agents, closing_proposals, k + 1


@pytest.mark.parametrize("name", sorted(MISSIONS))
@settings(max_examples=6, deadline=None)
@given(seed=st.integers(0, 10_000), open_steps=st.integers(5, 60))
def test_closed_swarm_loiters_apart(name: str, seed: int, open_steps: int) -> None:
    world, agents, proposals, k = _fly_then_close(name, seed, open_steps)
    assert proposals == 0, "a closing UAV proposes nothing new"
    assert all(a.commitments.loitering() for a in agents), "every UAV is in its loiter"
    lim = world.safety.limits
    rows = lim.rows([a.commitments.inforce for a in agents])
    pts, centres = expand_with_centres(rows, k, lim.reach.window, lim.kinematics_args)  # all later time
    mids = (pts[:, 1:] + pts[:, :-1]) / 2
    for track in (pts, mids):
        gaps = np.linalg.norm(track[:, None] - track[None, :], axis=-1)
        gaps[np.arange(len(agents)), np.arange(len(agents))] = np.inf
        assert gaps.min() > world.mission.comms.safety
    # and whatever their phases, at the radius ArduPlane flies them (the hand-over's AUTO loiters),
    # on near layers
    apart = np.linalg.norm(centres[:, None] - centres[None, :], axis=-1)
    apart[world.safety.near == 0] = np.inf
    apart[np.arange(len(agents)), np.arange(len(agents))] = np.inf
    assert apart.min() > 2 * FAILSAFE_WIDE * world.safety.loiter_radius + world.mission.comms.safety


def test_a_searching_swarm_is_not_loitering() -> None:
    """The check above can fail: without closing, trajectories in force still hold planned turns."""
    _, agents, _, _ = _fly_then_close("scenario1_continuous", 3, 10_000, close_after=40)
    assert not all(a.commitments.loitering() for a in agents)
