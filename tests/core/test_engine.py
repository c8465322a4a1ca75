"""Batch engine: reproducibility, wire equivalence, and the run-level properties of the paper.

No snapshot numbers: every check here is a property of the run (a metric recomputed from the
trajectory, a constraint, or equality between two ways of computing the same run).
"""

from __future__ import annotations

import math

import msgspec
import numpy as np
import pytest

from companion.batch.engine import RunResult, simulate
from companion.batch.montecarlo import run_specs, specs_for
from companion.core.connectivity import algebraic_connectivity, pairwise_distances
from companion.core.geometry import ConvexPolygon
from companion.core.kinematics import wrap_angle
from companion.core.world import build_world

FIELDS = ("uncertainty", "found", "coverage", "lambda2", "min_distance", "target_cells", "target_steps")


def assert_same(a: RunResult, b: RunResult) -> None:
    for name in FIELDS:
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    if a.trajectory is not None or b.trajectory is not None:
        assert np.array_equal(a.trajectory, b.trajectory)
        assert np.array_equal(a.tasks, b.tasks)


def lossy(mission, loss: float = 0.2):
    return msgspec.structs.replace(mission, comms=msgspec.structs.replace(mission.comms, loss=loss))


@pytest.mark.parametrize("loss", [0.0, 0.2])
def test_seeded_run_is_identical_bit_for_bit(scenario1, loss: float) -> None:
    m = lossy(scenario1, loss)
    a = simulate(m, seed=7, run=3, steps=60, record=True)
    b = simulate(m, seed=7, run=3, steps=60, record=True)
    assert_same(a, b)


def test_different_runs_are_different_instances(scenario1) -> None:
    a = simulate(scenario1, seed=7, run=0, steps=5)
    b = simulate(scenario1, seed=7, run=1, steps=5)
    c = simulate(scenario1, seed=8, run=0, steps=5)
    assert not np.array_equal(a.target_cells, b.target_cells)
    assert not np.array_equal(a.target_cells, c.target_cells)


def test_run_r_is_the_same_whatever_else_is_in_the_batch(scenario1) -> None:
    m = lossy(scenario1)
    alone = simulate(m, seed=5, run=2, steps=40, record=True)
    big = list(run_specs(specs_for(m, ["no-ta", "proposed"], 4, 40, 5, lambda r: True), workers=1))
    small = list(run_specs(specs_for(m, ["proposed"], 3, 40, 5, lambda r: True), workers=1))
    assert big[6].run == 2 and big[6].algorithm == "proposed"
    assert_same(alone, big[6])
    assert_same(alone, small[2])
    # run r of every algorithm sees the same targets
    assert np.array_equal(big[2].target_cells, big[6].target_cells)


@pytest.mark.parametrize("algorithm", ["proposed", "pheromone"])
def test_wire_gives_the_same_run(scenario1, algorithm: str) -> None:
    m = lossy(scenario1.with_algorithm(algorithm))
    assert_same(
        simulate(m, seed=3, run=1, steps=40, record=True, wire=False),
        simulate(m, seed=3, run=1, steps=40, record=True, wire=True),
    )


@pytest.fixture(scope="module")
def runs(scenario1) -> dict[str, RunResult]:
    return {
        a: simulate(scenario1.with_algorithm(a), seed=1, run=0, steps=150, record=True)
        for a in ("proposed", "no-ta", "pheromone")
    }


@pytest.mark.parametrize("algorithm", ["proposed", "no-ta", "pheromone"])
def test_trajectories_stay_in_the_fence_and_turn_at_most_45_degrees(scenario1, runs, algorithm: str) -> None:
    """The search stays in the region; a UAV may turn in the operating margin (the fence: the region
    with every edge pushed out by `safety.margin`), never beyond it, and seldom."""
    r = runs[algorithm]
    region = ConvexPolygon.from_vertices(scenario1.region.polygon)
    tr = r.trajectory
    depth = tr[..., None, :2] @ region.normals.T - region.offsets  # metres beyond each edge
    assert np.all(depth.max(axis=-1) <= scenario1.safety.margin + 1e-9)
    assert np.mean(region.contains(tr[..., 0], tr[..., 1])) >= 0.95
    assert np.all(np.abs(wrap_angle(np.diff(tr[..., 2], axis=0))) <= math.radians(45.0) + 1e-9)
    # grid mode: the UAVs move one cell per step, along their new heading
    step = np.diff(tr[..., :2], axis=0)
    assert np.all(np.isin(np.round(np.abs(step), 9), (0.0, 40.0)))
    heading = np.arctan2(step[..., 1], step[..., 0])
    assert np.allclose(wrap_angle(heading - tr[1:, :, 2]), 0.0, atol=1e-9)


@pytest.mark.parametrize("algorithm", ["proposed", "no-ta", "pheromone"])
def test_run_metrics_agree_with_the_trajectory(scenario1, runs, algorithm: str) -> None:
    r = runs[algorithm]
    tr = r.trajectory
    world = build_world(scenario1, 1, 0)
    for k in (0, 37, 149):
        assert r.lambda2[k] == pytest.approx(algebraic_connectivity(tr[k, :, :2], scenario1.comms.range))
        d = pairwise_distances(tr[k, :, :2])
        assert r.min_distance[k] == pytest.approx(d[~np.eye(4, dtype=bool)].min())
    # a target is found at the first step a UAV has its cell centre within R_A
    xy = world.grid.centres[r.target_cells]
    d2 = np.sum((tr[:, :, None, :2] - xy[None, None, :, :]) ** 2, axis=-1)
    seen = (d2 <= scenario1.sensor.radius**2 + 1e-6).any(axis=1)
    expected = np.where(seen.any(axis=0), seen.argmax(axis=0), -1)
    assert np.array_equal(r.target_steps, expected)
    assert np.array_equal(r.found, np.cumsum(np.bincount(expected[expected >= 0], minlength=150)))
    # eq. 30 never rises (no eta rises); coverage never falls and stays a fraction
    assert np.all(np.diff(r.uncertainty) <= 1e-15) and 0 < r.uncertainty[-1] < 1
    assert np.all(np.diff(r.coverage) >= 0) and 0 < r.coverage[-1] <= 1


@pytest.mark.parametrize("algorithm", ["proposed", "no-ta", "pheromone"])
def test_connected_and_safe_throughout(scenario1, runs, algorithm: str) -> None:
    """The paper: lambda_2 > 0 and the minimum inter-UAV distance > R_s throughout every run."""
    r = runs[algorithm]
    assert r.lambda2.min() > 0
    assert r.min_distance.min() > scenario1.comms.safety


def test_tasks_after_synchronisation(scenario1) -> None:
    """After the first auction, no task is held by two UAVs in direct range (the claims of UAVs out of
    range meet a few hops later: the next test), and a UAV without a task is one that
    could not get one: a UAV that drops a task (eqs. 20-21) bids at once and holds a new one a step
    later, unless it bid for nothing (every task it could keep complete or, by eq. 21, too costly)
    or every task it bid for went to others, or it won one that eq. 21 no longer let it keep a step
    later (it moved: that task's bid is then zero)."""
    for run in (0, 1, 2):
        bids: list[list[tuple[float, ...] | None]] = []
        r = simulate(
            scenario1,
            seed=1,
            run=run,
            steps=60,
            record=True,
            probe=lambda k, agents, log=bids: log.append([a.bids for a in agents]),
        )
        checked = 0
        for k in range(2, 60):
            if r.lambda2[k] <= 0:
                continue
            t, xy = r.tasks[k], r.trajectory[k - 1, :, :2]
            for i, j in zip(
                *np.nonzero(np.triu(t[:, None] == t[None, :], 1) & (t >= 0)[:, None]), strict=True
            ):
                # claims travel one hop per step: only UAVs out of direct range may hold one task
                assert np.hypot(*(xy[i] - xy[j])) > scenario1.comms.range, (run, k, t)
            for i in np.flatnonzero((r.tasks[k] < 0) & (r.tasks[k - 1] < 0)):
                wanted = {j for j, v in enumerate(bids[k - 1][i] or ()) if v > 0}
                taken = {int(t) for u, t in enumerate(r.tasks[k]) if u != i and t >= 0}
                now = bids[k][i] or (0.0,) * (max(wanted, default=0) + 1)
                lapsed = {j for j in wanted - taken if now[j] == 0}
                assert wanted <= taken or lapsed, (run, k, i, sorted(wanted - taken))
            checked += int(np.count_nonzero(r.tasks[k] >= 0))
        assert checked > 0


def test_conflicting_claims_resolve_within_the_synchronisation_delay(scenario3) -> None:
    """Claims travel one hop per step, so two UAVs that are not in direct range may claim the same
    task for a moment (scenario 3, seed 1, run 3, steps 175-176). The conflict must be gone within
    N steps (the longest multi-hop path is N - 1 hops)."""
    r = simulate(scenario3, seed=1, run=3, steps=200, record=True)
    n = scenario3.n_uavs
    streak = 0
    for k in range(1, 200):
        held = r.tasks[k][r.tasks[k] >= 0]
        streak = streak + 1 if len(set(held.tolist())) < len(held) else 0
        assert streak < n, (k, r.tasks[k])


def test_continuous_mode_trajectories_stay_in_the_fence(scenario1) -> None:
    """Continuous mode at a corner (scenario 1, pheromone, seed 1, run 0: before the safety layer
    UAV 0 left the region at step 323, the M = 3 step look-ahead with 45 degree turns unable to see
    that a corner needs a 4-step U-turn): every trajectory in force now ends in a loiter inside the
    fence, so no UAV ever leaves the fence, and it leaves the region only where the safety layer
    turns it into the operating margin (to keep another UAV's failsafe region clear), seldom: in
    1.3 % of UAV-steps here since loiters turn away from a near UAV (0.06 % before; the proposed
    method 0.4 % either way, runs 0-11)."""
    m = scenario1.with_algorithm("pheromone")
    m = msgspec.structs.replace(m, kinematics=msgspec.structs.replace(m.kinematics, mode="continuous"))
    r = simulate(m, seed=1, run=0, steps=400, record=True)
    region = ConvexPolygon.from_vertices(m.region.polygon)
    tr = r.trajectory
    assert np.all(np.abs(wrap_angle(np.diff(tr[..., 2], axis=0))) <= math.radians(45.0) + 1e-9)
    depth = tr[..., None, :2] @ region.normals.T - region.offsets  # metres beyond each edge
    assert np.all(depth.max(axis=-1) <= m.safety.margin + 1e-9)
    assert np.mean(region.contains(tr[..., 0], tr[..., 1])) >= 0.98
