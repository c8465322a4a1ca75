"""The loiter side a new proposal tries first (`Commitments.first_allowed`, `_turn_towards`): away
from the nearest UAV within `SIDE_RANGE` on a near layer, so that the two failsafe regions open
apart; towards the region's centroid when none is near, the near one is taken as gone, or it flies
a layer the vertical separation away."""

from __future__ import annotations

import math
from pathlib import Path

import msgspec
import numpy as np
import pytest

from companion.contracts.mission import Layers
from companion.core.commitment import SIDE_RANGE, Commitments
from companion.core.feasibility import load_mission
from companion.core.messages import UavState
from companion.core.trajectory import Trajectory
from companion.core.world import build_world

ROOT = Path(__file__).resolve().parents[2]


def _commitments(
    peer: tuple[float, float], stamp: int = 4, layers: int = 1
) -> tuple[Commitments, np.ndarray]:
    mission = load_mission(ROOT / "mission_files" / "scenario1.toml")
    world = build_world(msgspec.structs.replace(mission, layers=Layers(count=layers)))
    c = Commitments(world, 0)
    c.latest = {1: UavState(1, stamp, peer[0], peer[1], 0.0, ())}
    c.observe(5, {}, [])
    return c, np.asarray(world.grid.region.vertices.mean(axis=0))


@pytest.mark.parametrize("bearing", [0.0, 1.0, 2.5, 4.0, 5.5])
def test_a_near_uav_is_turned_away_from(bearing: float) -> None:
    x, y, d = 100.0, -200.0, 0.5 * SIDE_RANGE
    peer = (x + d * math.cos(bearing), y + d * math.sin(bearing))
    c, _ = _commitments(peer)
    tx, ty = c._turn_towards(x, y)
    # the point lies on the far side of (x, y) from the peer, on the line through both
    assert (tx - x) * (peer[0] - x) + (ty - y) * (peer[1] - y) < 0
    assert abs((tx - x) * (peer[1] - y) - (ty - y) * (peer[0] - x)) < 1e-6 * math.hypot(tx - x, ty - y) * d


def test_without_a_near_uav_the_loiter_turns_to_the_centroid() -> None:
    c, centroid = _commitments((100.0 + 1.5 * SIDE_RANGE, -200.0))
    assert np.array_equal(c._turn_towards(100.0, -200.0), centroid)


def test_a_uav_taken_as_gone_is_not_turned_away_from() -> None:
    c, centroid = _commitments((150.0, -200.0), stamp=-10)  # silent far longer than the timeout
    assert 1 in c.dead
    assert np.array_equal(c._turn_towards(100.0, -200.0), centroid)


def test_a_uav_on_another_layer_is_not_turned_away_from() -> None:
    c, centroid = _commitments((150.0, -200.0), layers=4)  # UAVs 0 and 1 on layers 20 m apart
    assert not c.near[1]
    assert np.array_equal(c._turn_towards(100.0, -200.0), centroid)


@pytest.mark.parametrize("peer_y", [-550.0, 550.0])
def test_the_proposal_loiters_on_the_side_away_from_a_near_uav(peer_y: float) -> None:
    """Through `first_allowed`: with nothing gathered to check against (the UAV abeam is only
    known, not a constraint), the straightest path is taken with the side tried first, whose loiter
    centre lies on the far side from the UAV abeam."""
    c, _ = _commitments((0.0, peer_y))
    lim, k = c.limits, 5
    order = np.arange(len(c.world.paths.sequences), dtype=np.int64)
    best, side = c.first_allowed(k, (0.0, 0.0, 0.0), order)
    assert best >= 0
    turns = tuple(c.world.paths.sequences[best].tolist())
    centre_y = {s: lim.loiter_circle(Trajectory(k + 1, 0.0, 0.0, 0.0, turns, s))[1] for s in (1, -1)}
    assert abs(centre_y[side] - peer_y) > abs(centre_y[-side] - peer_y)
