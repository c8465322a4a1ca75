"""The fault matrix (docs/reliability.md): each row flown by real processes on loopback (the
simulator in lockstep, one companion per UAV with its journal), the fault struck at a step, and the
outcome measured by `companion.app.faults.measure`: mission completed, no detection lost, no
separation lost (the simulator's own closest approach at its physics rate), knowledge converged.
The long versions: `uavsearch faults --row all`."""

from __future__ import annotations

import csv
from pathlib import Path

import pytest

from companion.app.faults import ROWS, Plan, run_row
from companion.core.feasibility import load_mission
from tests.e2e.conftest import SCENARIO1, searched

PLAN = Plan(steps=40, at=12, outage=8, victim=1)
RECOVER_STEPS = 20  # after a partition heals (tests/core/test_recovery.py)


def _rows(path: Path) -> list[dict[str, float]]:
    """The mission's rows of a step log (run_row checks the fly-out after them)."""
    with path.open(newline="") as f:
        rows = [{k: float(v) for k, v in r.items()} for r in csv.DictReader(f) if r["step"].isdigit()]
    return searched(rows)


@pytest.mark.slow
@pytest.mark.parametrize("row", ROWS)
def test_fault_row(row: str, tmp_path: Path) -> None:
    mission = load_mission(SCENARIO1)
    outcome = run_row(row, mission, tmp_path, PLAN)
    losses_only = len(outcome.failures) == 1 and outcome.failures[0].startswith(
        f"{outcome.separation_losses} steps within R_s"
    )
    if losses_only:
        with (tmp_path / "approach.csv").open() as f:
            near = [r for r in csv.DictReader(f) if float(r["distance_m"]) <= mission.comms.safety]
        pairs = {(int(r["i"]), int(r["j"])) for r in near}
    if row == "partition" and losses_only:
        # the known gap between UAVs sharing a layer (docs/algorithm.md, "A partition at close
        # range"): each group takes the other as gone and flies on; only pairs across the split may
        # come within R_s, and once the groups hear each other again the safety layer's recovery gets
        # them apart within a few steps. Pairs on layers apart keep their vertical separation.
        half = mission.n_uavs // 2
        assert all((i < half) != (j < half) for i, j in pairs), near
        shared = mission.near_layers()
        assert all(shared[i][j] for i, j in pairs), f"pairs on layers apart lost 3D separation: {near}"
        last = max(int(r["step"]) for r in near)
        assert last <= PLAN.at + PLAN.outage + RECOVER_STEPS, f"within R_s until step {last}"
        pytest.xfail(f"two UAVs across the partition came {outcome.closest_approach_m:.1f} m apart")
    assert not outcome.failures, outcome
    assert outcome.completed and outcome.converged and outcome.detections > 0
    assert outcome.separation_losses == 0
    # live peers that hear each other keep R_s horizontally whatever their layers; a vehicle flying
    # alone (a companion restarting, a link cut) or a partition is a failure the layers guard
    # (docs/algorithm.md, "Separation in three dimensions")
    if row == "loss":
        assert outcome.closest_approach_m > 60.0
    victim = _rows(tmp_path / f"uav{PLAN.victim}.csv")
    steps = [int(r["step"]) for r in victim]
    if row == "restart":
        # killed after `at`; its vehicle flew on alone; the restarted companion went on from the
        # vehicle's step, with the map, targets and task it had (not from step 0 and eta_0 = 1)
        killed = outcome.notes["killed_after_step"]
        resumed = min(k for k in steps if k > killed)
        assert resumed == killed + PLAN.outage
        by_step = {int(r["step"]): r for r in victim}
        assert by_step[resumed]["mean_eta"] <= by_step[killed]["mean_eta"] < 1.0
        assert by_step[resumed]["found"] >= by_step[killed]["found"]
        assert any(by_step[k]["task"] >= 0 for k in steps if k >= resumed)
        assert "restarted from journal" in (tmp_path / "companion1.2.log").read_text()
    elif row == "sim-restart":
        assert "resumed from" in (tmp_path / "sim.2.log").read_text()
        assert steps == list(range(PLAN.steps))  # no step lost or flown twice
    elif row == "link-loss":
        first, last = outcome.notes["vehicle_alone_steps"]
        assert last - first >= 5  # 10 s of simulated time at 2 s a step, flown without guidance
        assert set(range(first + 1, last)).isdisjoint(steps)  # the step in flight when cut may end
        assert outcome.notes["proxy_dropped_datagrams"] > 0
    else:
        assert all(d > 0 for d in outcome.notes["fault_dropped"])
