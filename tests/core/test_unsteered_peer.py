"""A UAV whose companion does not steer its vehicle (`UavState.steered = False`): it commits to
nothing, its peers keep clear of a disk about its latest report (`Commitments.adrift_reach`), and
nobody keeps or takes it as a tether."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from companion.core.agent import Agent, Observation
from companion.core.commitment import Commitments
from companion.core.feasibility import load_mission
from companion.core.messages import MessageError, StateMsg, UavState, check
from companion.core.trajectory import Trajectory
from companion.core.world import FAILSAFE_WIDE, build_world

ROOT = Path(__file__).resolve().parents[2]
WORLD = build_world(load_mission(ROOT / "mission_files" / "scenario1.toml"))


def _fresh(state: UavState) -> StateMsg:
    return StateMsg(sender=state.uav, stamp=state.stamp, x=state.x, y=state.y, state=state)


def test_an_unsteered_peer_is_a_disk_about_its_latest_report_and_no_tether() -> None:
    s = WORLD.safety
    child = next(i for i, p in enumerate(s.parents) if p >= 0)
    parent = s.parents[child]
    c = Commitments(WORLD, child)
    assert c.parents == (parent,)
    steered = UavState(
        parent, 4, 10.0, 20.0, 0.0, (), committed=Trajectory(4, 10.0, 20.0, 0.0, (0.0,) * 3, 1)
    )
    c.observe(5, {parent: _fresh(steered)}, [steered])
    assert parent not in c.dead
    adrift = UavState(parent, 5, 30.0, 40.0, 1.0, (), steered=False)
    c.observe(6, {parent: _fresh(adrift)}, [adrift])
    assert parent in c.dead
    assert c.failsafe_loiters(parent) == [(30.0, 40.0, c.adrift_reach)]
    assert c.adrift_reach == s.failsafe_reach + FAILSAFE_WIDE * s.loiter_radius
    c.update_parents(6, np.array([0.0, 0.0]))
    assert parent not in c.parents
    steered_again = UavState(
        parent, 6, 31.0, 41.0, 1.0, (), committed=Trajectory(6, 31.0, 41.0, 1.0, (0.0,) * 3, 1)
    )
    c.observe(7, {parent: _fresh(steered_again)}, [steered_again])
    assert parent not in c.dead  # steered again: its commitments count once more


def test_a_state_of_an_unsteered_vehicle_with_commitments_is_refused() -> None:
    t = Trajectory(5, 0.0, 0.0, 0.0, (0.0,) * 3, 1)
    bad = UavState(1, 5, 0.0, 0.0, 0.0, (), committed=t, steered=False)
    with pytest.raises(MessageError, match="does not steer"):
        check(_fresh(bad), 4, WORLD.grid.n_cells, 4)
    check(_fresh(UavState(1, 5, 0.0, 0.0, 0.0, (), steered=False)), 4, WORLD.grid.n_cells, 4)


def test_an_agent_told_it_is_not_steered_publishes_no_commitments_and_proposes_nothing() -> None:
    agent = Agent(WORLD, 0)
    v = WORLD.mission.vehicles[0]
    pose = {"x": v.x, "y": v.y, "heading": np.radians(v.heading_deg)}
    _, out = agent.step(Observation(step=0, **pose), [])
    me = next(m for m in out if isinstance(m, StateMsg)).state
    assert me.steered and me.committed is not None and me.proposal is not None
    _, out = agent.step(Observation(step=1, **pose, steered=False), [])
    me = next(m for m in out if isinstance(m, StateMsg)).state
    assert not me.steered and me.committed is None and me.proposal is None and me.plan == ()
    assert agent.commitments.proposal is None
