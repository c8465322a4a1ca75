"""Smoke test of the simulator's benchmark (`python -m sim_vehicles.bench`): its missions are valid
and a short run of real processes on loopback returns figures from a simulator its clients reached.
No timing assertion: the machine may be loaded."""

from __future__ import annotations

import pytest

from companion.core.feasibility import parse_mission
from sim_vehicles.bench import DEFAULT_MISSION, _mission_text, measure


@pytest.mark.parametrize("n", [1, 4, 50])
def test_bench_missions_validate(n: int) -> None:
    mission = parse_mission(_mission_text(DEFAULT_MISSION, n), f"bench mission of {n}")
    assert mission.n_uavs == n


@pytest.mark.timeout(180)
def test_a_short_run_returns_figures() -> None:
    r = measure(DEFAULT_MISSION, 4, 5.0, 1.5)
    assert r.vehicles == 4 and r.speedup == 5.0
    assert r.achieved_speedup > 0 and r.cpu_share > 0
    assert r.messages_per_s > 0  # the vehicles answered their clients with telemetry
    assert r.slipped_s >= 0
