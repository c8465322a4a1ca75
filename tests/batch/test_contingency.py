"""The contingency clause (docs/algorithm.md, "Safety layer"): once a pair of UAVs' trajectories in
force clear each other's failsafe regions (where the other's aircraft flies if its companion falls
silent: off its path until the failsafe fires, then onto its loiter and around it, at a phase of
its own), every later pair of trajectories in force does; a pair closer than that never gets
closer by the clause's measure. Generated missions (any convex region, 3-10 UAVs, both
kinematics, all three algorithms, edge and clustered starts, one layer or several: the clause guards
pairs on near layers only), and the paper's scenarios on one layer, which clear it from their
first step."""

from __future__ import annotations

from pathlib import Path

import msgspec
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from companion.batch.engine import simulate
from companion.contracts.mission import Layers, Mission
from companion.core.feasibility import load_mission
from companion.core.world import build_world
from tests.batch.contingency import clause_probe, clear_pairs
from tests.batch.strikes import MISSION_ARGS, struck_mission

ROOT = Path(__file__).resolve().parents[2]
STEPS = 400


def _clauses(m, steps: int):
    world = build_world(m, m.seed, 0)
    rows: list = []
    r = simulate(m, m.seed, 0, steps, world=world, probe=clause_probe(world, rows))
    return r, clear_pairs(rows), np.array(rows)


@pytest.mark.slow
@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(**MISSION_ARGS)
def test_a_pair_that_clears_the_clause_keeps_clearing_it(
    seed: int, mode: str, algorithm: str, data: st.DataObject
) -> None:
    m, _ = struck_mission(seed, mode, algorithm, data, STEPS, "unused")
    r, clear, gaps = _clauses(m, STEPS)
    assert r.separation_losses == 0
    lost = clear[:-1] & ~clear[1:]
    assert not lost.any(), f"a pair stopped clearing the clause at step {int(lost.any(axis=1).argmax()) + 1}"
    iu = np.triu_indices(m.n_uavs, 1)
    pairs = gaps[:, iu[0], iu[1]]
    closer = (pairs[1:] < pairs[:-1] - 1e-6) & ~clear[:-1]
    step = int(closer.any(axis=1).argmax()) + 1
    assert not closer.any(), f"a pair inside the clause got closer at step {step}"


def _one_layer(name: str, **safety: object) -> Mission:
    """A scenario with every UAV on one layer, so that the clause guards every pair."""
    m = load_mission(ROOT / "mission_files" / f"{name}.toml")
    return msgspec.structs.replace(
        m, layers=Layers(count=1), safety=msgspec.structs.replace(m.safety, **safety)
    )


@pytest.mark.parametrize("name", ["scenario1_continuous", "scenario2", "scenario3"])
def test_the_paper_scenarios_clear_it_throughout(name: str) -> None:
    _, clear, _ = _clauses(_one_layer(name), 200)
    assert clear.all()


def test_pairs_on_layers_apart_are_not_held_to_it() -> None:
    """At the defaults (a layer each) the clause guards no pair of the scenario: no pair is probed,
    and the RHC's first choice is refused less often than on one layer."""
    m = load_mission(ROOT / "mission_files" / "scenario3.toml")
    r, clear, _ = _clauses(m, 200)
    assert clear.all() and not m.near_layers()[0][1]
    one, _, _ = _clauses(_one_layer("scenario3"), 200)
    share = [x.extras["first_choices_refused"] / x.extras["first_choices"] for x in (r, one)]
    assert share[0] < share[1], share


def test_without_the_clause_pairs_come_inside_each_others_disks() -> None:
    """The checks above can fail: with `safety.contingency = false` the same scenario does not clear
    it (the equal-time compatibility alone lets UAVs pass close to each other's loiters)."""
    _, clear, _ = _clauses(_one_layer("scenario3", contingency=False), 200)
    assert not clear.all()
