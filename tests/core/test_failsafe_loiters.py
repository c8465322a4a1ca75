"""The survivors' model of where a gone UAV's aircraft circles (`Commitments.failsafe_loiters`):
the loiters of its last announced trajectory in force and proposal, and of the trajectory in force
it announced before, which its autopilot still holds if the companion died after publishing a
step and before moving the failsafe mission (`companion.node.failsafe`: upload after publish)."""

from __future__ import annotations

from pathlib import Path

from companion.core.commitment import Commitments
from companion.core.feasibility import load_mission
from companion.core.messages import UavState
from companion.core.trajectory import Trajectory
from companion.core.world import build_world

ROOT = Path(__file__).resolve().parents[2]


def _state(uav: int, stamp: int, committed: Trajectory) -> UavState:
    return UavState(uav, stamp, committed.x, committed.y, committed.heading, (), committed=committed)


def test_the_trajectory_in_force_announced_before_is_modelled_too() -> None:
    world = build_world(load_mission(ROOT / "mission_files" / "scenario1.toml"))
    c = Commitments(world, 0)
    lim, turn = world.safety.limits, world.safety.limits.reach.loiter_turn
    m = lim.horizon
    straight = Trajectory(3, 0.0, 0.0, 0.0, (0.0,) * m, 1)
    turned = Trajectory(4, 0.0, 0.0, 0.0, (turn,) * m, -1)  # its loiter lies elsewhere
    c.observe(4, {}, [_state(1, 3, straight)])
    c.observe(5, {}, [_state(1, 4, turned)])
    centres = {(round(x, 6), round(y, 6)) for x, y, _ in c.failsafe_loiters(1)}
    assert len(centres) == 2, "two trajectories with loiters apart"
    for t in (straight, turned):
        cx, cy, _ = lim.loiter_circle(t)
        assert (round(cx, 6), round(cy, 6)) in centres
    assert all(r == world.safety.failsafe_reach for *_, r in c.failsafe_loiters(1))
    c.observe(6, {}, [_state(1, 4, straight)])  # not newer: changes nothing
    assert len(c.failsafe_loiters(1)) == 2
