"""Altitude layers (`[layers]`, `Mission.altitude_of`, `mission.assign_layers`): every UAV its own
layer by default, those sharing one far apart at the start, and a clear error for a band or a layer
that cannot be flown (docs/algorithm.md, "Separation in three dimensions")."""

from __future__ import annotations

import math
import re

import pytest
from hypothesis import given
from hypothesis import strategies as st

from companion.contracts.mission import assign_layers
from companion.core.feasibility import load_mission, parse_mission

from .conftest import MISSIONS
from .test_mission import BASE, bad


def with_layers(table: str, text: str = BASE) -> str:
    return f"{text}\n[layers]\n{table}\n"


@pytest.mark.parametrize("name", ["scenario1", "scenario2", "scenario3", "scenario1_continuous"])
def test_the_scenarios_fly_a_layer_each_without_an_edit(name: str) -> None:
    m = load_mission(MISSIONS / f"{name}.toml")
    alts = [m.altitude_of(i) for i in range(m.n_uavs)]
    assert alts == [100.0, 120.0, 140.0, 160.0]
    near = m.near_layers()
    assert all(near[i][j] == (i == j) for i in range(4) for j in range(4))


def test_one_layer_for_everyone_by_saying_so() -> None:
    m = parse_mission(with_layers("count = 1"))
    assert {m.altitude_of(i) for i in range(m.n_uavs)} == {100.0}
    assert all(all(row) for row in m.near_layers())


def test_layers_spread_over_the_band() -> None:
    m = parse_mission(with_layers("band = 90.0\nseparation = 30.0\ncount = 2"))
    assert m.layer_count == 2
    assert sorted({m.altitude_of(i) for i in range(m.n_uavs)}) == [100.0, 190.0]


def test_a_band_too_thin_for_two_layers_is_an_error() -> None:
    err = bad(with_layers("band = 10.0\nseparation = 20.0"))
    assert err.field == "layers.band" and "layers.count = 1" in err.reason


def test_more_layers_than_the_band_holds_is_an_error() -> None:
    err = bad(with_layers("band = 40.0\nseparation = 20.0\ncount = 4"))
    assert err.field == "layers.count" and "60 m" in err.reason


def test_a_pinned_layer_outside_the_band_is_an_error() -> None:
    text = re.sub(r"^heading_deg = 90\.0.*$", "layer = 7\nheading_deg = 90.0", BASE, count=1, flags=re.M)
    err = bad(text)
    assert err.field == "vehicles[0].layer" and "0..3" in err.reason


def test_a_pinned_layer_is_kept() -> None:
    text = re.sub(r"^heading_deg = 90\.0.*$", "layer = 3\nheading_deg = 90.0", BASE, count=1, flags=re.M)
    m = parse_mission(text)
    assert m.layer_assignment()[0] == 3
    assert sorted(m.layer_assignment()) == [0, 1, 2, 3]


def test_the_old_altitude_step_names_its_replacement() -> None:
    err = bad(BASE.replace("altitude = 100.0", "altitude = 100.0\naltitude_step = 15.0"))
    assert err.field == "kinematics.altitude_step" and "[layers]" in err.reason


def test_the_lowest_layer_is_above_the_origin() -> None:
    err = bad(BASE.replace("altitude = 100.0", "altitude = -5.0"))
    assert err.field == "kinematics.altitude"


points = st.tuples(st.floats(-1000, 1000), st.floats(-1000, 1000))


@given(starts=st.lists(points, min_size=1, max_size=16), count=st.integers(1, 6))
def test_uavs_sharing_a_layer_start_far_apart(starts: list[tuple[float, float]], count: int) -> None:
    """Every layer is used before any is shared, and each UAV's layer was, when it chose, the one
    whose nearest member was farthest from it (the greedy choice `assign_layers` documents)."""
    layers = assign_layers(starts, [None] * len(starts), count)
    assert all(0 <= layer < count for layer in layers)
    assert len(set(layers)) == min(count, len(starts))  # an empty layer is taken before a shared one
    for i in range(len(starts)):

        def nearest(layer: int, i: int = i) -> float:
            return min(
                (math.dist(starts[i], starts[j]) for j in range(i) if layers[j] == layer), default=math.inf
            )

        assert nearest(layers[i]) >= max(nearest(layer) for layer in range(count))


def test_a_shared_layer_goes_to_the_farthest_pair() -> None:
    """Three UAVs on two layers: the third shares a layer with the UAV 900 m away, not 100 m."""
    assert assign_layers([(0.0, 0.0), (1000.0, 0.0), (100.0, 0.0)], [None] * 3, 2) == (0, 1, 1)
