"""Separation and connectivity hold on generated missions (docs/algorithm.md, "Safety layer"): any
convex region, 2-12 UAVs starting on an edge or clustered, 1-6 prior centres, grid and continuous
kinematics, all three algorithms, 1,000 steps each, in the batch engine; with a companion that
dies mid-run, and with message loss. The same generator drives `uavsearch soak` for long soaks."""

from __future__ import annotations

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from companion.batch.generate import Family
from companion.batch.montecarlo import execute
from companion.batch.soak import row_of, soak_specs
from companion.contracts.mission import ALGORITHMS

STEPS = 1000


def assert_clean(specs: list) -> None:
    for spec in specs:
        row = row_of(spec, execute(spec))
        assert row.separation_losses == 0, row
        assert row.link_losses == 0, row
        assert row.closest_approach > spec.mission.comms.safety
        assert row.recovered == 0, row  # the invariant held: no trajectory in force had to be replaced


@pytest.mark.slow
@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    seed=st.integers(0, 2**31 - 1),
    mode=st.sampled_from(["grid", "continuous"]),
    layout=st.sampled_from(["edge", "clustered"]),
    uavs=st.integers(2, 12),
)
def test_no_algorithm_loses_separation_or_a_link_on_generated_missions(
    seed: int, mode: str, layout: str, uavs: int
) -> None:
    family = Family(uavs=(uavs, uavs), modes=(mode,), layouts=(layout,), steps=STEPS)
    specs = soak_specs(1, seed, STEPS, ALGORITHMS, family=family)
    assert [s.mission.n_uavs for s in specs] == [uavs] * 3
    assert specs[0].mission.kinematics.mode == mode
    assert_clean(specs)


@pytest.mark.slow
@pytest.mark.parametrize("seed", [11, 12, 13])
def test_a_uav_whose_companion_dies_stays_an_obstacle(seed: int) -> None:
    """Its vehicle flies on along its last trajectory in force; the others keep clear of it (the
    closest approach counts every pair, the silent UAV included)."""
    family = Family(uavs=(4, 8), steps=STEPS)
    specs = soak_specs(1, seed, STEPS, ("proposed",), kill=True, family=family)
    assert specs[0].kills
    assert_clean(specs)


@pytest.mark.slow
@pytest.mark.parametrize("seed", [21, 22])
def test_separation_holds_under_message_loss(seed: int) -> None:
    specs = soak_specs(1, seed, STEPS, ("proposed",), loss=0.3, family=Family(uavs=(4, 8), steps=STEPS))
    for spec in specs:
        row = row_of(spec, execute(spec))
        assert row.separation_losses == 0, row


@pytest.mark.slow
@settings(max_examples=4, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**31 - 1), mode=st.sampled_from(["grid", "continuous"]))
def test_no_algorithm_enters_a_no_fly_zone_even_when_a_companion_dies(seed: int, mode: str) -> None:
    """Generated missions with 1-3 no-fly zones (circles and bars): no chord of any UAV, the dead
    one's failsafe flight included, enters a zone inflated by the margin (docs/algorithm.md,
    "No-fly zones and non-convex regions"), and separation holds."""
    family = Family(uavs=(3, 8), modes=(mode,), steps=600, zones=(1, 3))
    specs = soak_specs(1, seed, 600, ALGORITHMS, kill=True, family=family)
    assert specs[0].mission.region.nofly
    for spec in specs:
        row = row_of(spec, execute(spec))
        assert row.keepout_entries == 0, row
        assert row.separation_losses == 0, row
