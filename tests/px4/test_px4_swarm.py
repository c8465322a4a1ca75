"""A swarm on PX4 SITL with one command: `uavsearch run --autopilot px4-sitl`.

Three PX4 instances (SIH fixed-wing, SWARM_SPEEDUP times real time), the stand-alone camera, three
companions taking off by themselves to their altitude layers and flying the plan in OFFBOARD
(position-target). The run is stopped with Ctrl-C once every UAV steered STEPS steps and the swarm
found a target as the run's score counts it (a camera frame between sampling moments may see a
target at the edge of the field of view that the score, which looks at the sampling moments, does
not), and is scored: targets found, every logged pose inside the fence, every steered step of each
UAV within ALTITUDE_KEEPING of its altitude layer, the plan kept within the mission's safety buffer
(on 95 % of steps), and separation along the flown tracks (approach.csv): in three dimensions
throughout, take-offs included, and R_s horizontally between every two UAVs both steered by their
companions since the step before (a UAV joins where its autopilot's take-off left it).
"""

from __future__ import annotations

import csv
import json
import statistics
import time
from pathlib import Path

from companion.app.evaluation import CompanionLogs, evaluate, losses_3d, truth_cells
from companion.app.px4_sitl import Px4Build
from companion.core.world import World, build_world
from tests.e2e.conftest import PY, Proc, Procs, assert_at_layer_while_steered, read_csv, wait_rows
from tests.px4.conftest import SWARM_SPEEDUP, first_instance, write_mission

UAVS, STEPS, MAX_STEPS = 3, 40, 400


def wait_scored_target(world: World, out: Path, run: Proc, timeout: float) -> None:
    """Wait until the logs so far score a target found (`evaluation.evaluate` on `CompanionLogs`, as
    the run's report does at the end: a target once found stays found as more steps are logged)."""
    logs, truth = CompanionLogs(out, UAVS), out / "truth.json"
    deadline = time.monotonic() + timeout
    while True:
        logs.poll()
        if all(logs.logs.values()) and truth.exists():
            scored = evaluate(world, logs.logs, truth_cells(truth), 0.0, world.mission.seed)
            if (scored.target_steps >= 0).any():
                return
        assert run.alive(), run.text()
        assert time.monotonic() < deadline, f"no target scored within {timeout:.0f} s"
        time.sleep(1.0)


def test_swarm_on_px4_sitl(px4_build: Px4Build, tmp_path: Path) -> None:
    mission = write_mission(tmp_path, UAVS)
    m = mission.mission
    out = tmp_path / "out"
    procs = Procs(tmp_path)
    argv = [PY, "-m", "companion.cli", "run", str(mission.path), "--autopilot", "px4-sitl"]
    argv += ["--speedup", f"{SWARM_SPEEDUP:g}", "--steps", str(MAX_STEPS), "--out", str(out), "--quiet"]
    argv += ["--keep-going", "--sitl-instance", str(first_instance())]
    try:
        run = procs.start("run", argv)
        for i in range(UAVS):  # STEPS steps each, and on until the swarm has found a target
            wait_rows(out / f"uav{i}.csv", STEPS, run, timeout=600, cond=lambda r: r["steered"] == 1)
        wait_scored_target(build_world(m), out, run, timeout=600)
        assert run.stop(timeout=60) == 0, run.text()  # Ctrl-C: the run ends with its report
    finally:
        procs.stop_all()

    assert "pass criteria met" in run.text(), run.text()
    summary = json.loads((out / "summary.json").read_text())["proposed"]
    assert summary["targets_found_fraction"] > 0, summary
    tracking = json.loads((out / "tracking.json").read_text())
    assert tracking["outside_fence"] == 0 and tracking["steps"] >= UAVS * (STEPS - 10), tracking
    assert tracking["position_m"]["p95"] <= m.safety.buffer, (tracking["position_m"], m.safety.buffer)
    logs = {i: {int(r["step"]): r for r in read_csv(out / f"uav{i}.csv")} for i in range(UAVS)}
    for i, rows in logs.items():
        flown = [r for r in rows.values() if r["steered"]][5:]
        assert len(flown) >= STEPS - 10, f"uav{i} steered {len(flown)} steps"
        assert abs(statistics.median(r["up"] for r in flown) - m.altitude_of(i)) < 5.0, (
            f"uav{i} off its layer"
        )
        assert_at_layer_while_steered(m, i, rows)
    # separation along the flown tracks (the stand-alone camera's time-aligned position streams): each
    # PX4 instance keeps its own clock, so the poses the companions log at step k are not simultaneous.
    # In three dimensions over the whole record, take-offs included (`losses_3d`: within R_s
    # horizontally, at least the layers' floor apart vertically); R_s horizontally between every two
    # UAVs both steered by their companions since the step before (the paper's protocol between live
    # peers; an aircraft joins it where its autopilot's take-off left it, kept apart by its layer)
    approach = out / "approach.csv"
    assert losses_3d(approach, m) == 0, f"lost 3D separation (vertical floor {m.vertical_floor:g} m)"
    with approach.open() as f:  # every pair within 3 R_s, and each step's closest
        rows = list(csv.DictReader(f))
    pairs = [(int(r["step"]), int(r["i"]), int(r["j"]), float(r["distance_m"])) for r in rows]
    steered = {i: {k for k, r in rows.items() if r["steered"]} for i, rows in logs.items()}
    live = [d for k, i, j, d in pairs if {k - 1, k} <= steered[i] and {k - 1, k} <= steered[j]]
    assert len(live) >= STEPS - 10, f"{len(live)} pair-steps with both UAVs steered in the separation record"
    assert min(live) > m.comms.safety, f"closest approach of two steered UAVs {min(live):.1f} m"
