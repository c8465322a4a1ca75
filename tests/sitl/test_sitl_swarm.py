"""A whole swarm on ArduPlane SITL with one command: `uavsearch run --autopilot ardupilot-sitl`.

Four SITL instances (speed-up 4), the stand-alone camera, four companions taking off by themselves
at their altitude layers (one each), each arming its autopilot's failsafe for its own silence and
keeping it on the loiter of its trajectory in force. UAV 1 starts 140 m from UAV 2, on the layer
next to it. A radio partition ({0, 1} against {2, 3}, the fault matrix's partition row) cuts that
pair apart while both are in range, and UAV 1's companion is then killed mid-partition: its aircraft
flies its last guidance for `safety.failsafe_timeout` (one step, the default), then ArduPlane's GCS
failsafe switches it to AUTO and it circles that loiter (seen on a ground station of our own, SITL's
SERIAL2), within `safety.failsafe_reach` of the loiter's centre. The others fly on; the run,
stopped with Ctrl-C, is scored: targets found, every logged pose inside the fence, each UAV at its
altitude layer, and separation in three dimensions (docs/algorithm.md, "Separation in three
dimensions"): in the camera's record of every pair's closest approach (approach.csv, from the
vehicles' position streams at 10 Hz, with their altitudes) no two aircraft are within R_s
horizontally and closer vertically than the layers' floor, at any time.
"""


from __future__ import annotations

import csv
import itertools
import json
import math
import os
import signal
import statistics
from pathlib import Path

from companion.app.evaluation import losses_3d
from companion.contracts.frames import LocalFrame
from companion.core.world import FAILSAFE_WIDE, build_world
from companion.node.vehicle_link import VehicleLink
from tests.e2e.conftest import PY, Procs, companion_pid, read_csv, wait_rows
from tests.sim.conftest import fit_circle
from tests.sitl.conftest import GCS_COMPONENT, write_mission

VICTIM = 1
KILL_AFTER = 8  # steps the victim logs before it is killed
SURVIVOR_STEPS = 40  # steps every other UAV logs after the kill
AUTO = 10
CIRCLING_S = 60.0  # simulated seconds the victim's aircraft is watched circling after its failsafe
FAILSAFE_S = 60.0  # simulated seconds after the kill by which the failsafe must have fired
FAILSAFE_TIMEOUT_S = 2.0  # FS_LONG_TIMEOUT (one step): 0.5 s of wall time at speed-up 4
NEIGHBOUR = 2  # on the layer next to the victim's, 140 m from it at the start
STARTS = [(-620.0, -980.0), (-20.0, -980.0), (120.0, -980.0), (580.0, -980.0)]
PARTITION = (4, 90)  # steps [start, end): {0, 1} hear nothing of {2, 3}, across the kill


def test_swarm_on_sitl_with_a_companion_killed(sitl_binary: Path, tmp_path: Path) -> None:
    start, end = PARTITION
    partition = f"\n[[faults.network]]\nstart = {start}\nend = {end}\ngroups = [[0, 1], [2, 3]]\n"
    safety = f"failsafe_timeout = {FAILSAFE_TIMEOUT_S}"
    mission = write_mission(tmp_path, 4, starts=STARTS, safety=safety, extra=partition)
    m = mission.mission
    assert abs(m.altitude_of(VICTIM) - m.altitude_of(NEIGHBOUR)) == m.layers.separation  # adjacent
    out = tmp_path / "out"
    procs = Procs(tmp_path)
    argv = [PY, "-m", "companion.cli", "run", str(mission.path), "--autopilot", "ardupilot-sitl"]
    argv += ["--speedup", "4", "--steps", "1000", "--out", str(out), "--quiet", "--keep-going"]
    try:
        run = procs.start("run", argv)
        victim_pid = companion_pid(run, VICTIM)
        wait_rows(out / f"uav{VICTIM}.csv", KILL_AFTER, run, timeout=240)
        assert "failsafe armed" in (out / f"companion{VICTIM}.log").read_text()
        frame = LocalFrame(m.region.origin)
        ports = mission.ports(VICTIM)
        gcs = VehicleLink(ports.url(ports.serial2), frame, component=GCS_COMPONENT)
        gcs.wait_heartbeat(30)
        gcs.request_streams()
        os.kill(victim_pid, signal.SIGKILL)
        last = read_csv(out / f"uav{VICTIM}.csv")[-1]
        killed_at, report = int(last["step"]), (last["x"], last["y"])
        assert PARTITION[0] < killed_at < PARTITION[1], f"killed at step {killed_at}, not mid-partition"

        s = gcs.state
        while not s.has_pose:
            gcs.poll(0.2)
        t_kill, failsafe, track, ups = s.time_s, None, [], []
        s.texts.clear()
        while failsafe is None or s.time_s < failsafe[0] + CIRCLING_S:
            gcs.poll(0.1)
            track.append((s.time_s, (s.x, s.y)))
            ups.append(s.up)
            if failsafe is None:
                assert s.time_s < t_kill + FAILSAFE_S, f"no failsafe by t = {s.time_s:.0f} s: {s.texts}"
                if "GCS Failsafe On: AUTO" in s.texts:
                    failsafe = (s.time_s, (s.x, s.y))
        assert s.custom_mode == AUTO
        gcs.close()
        for i in range(m.n_uavs):
            if i != VICTIM:
                wait_rows(
                    out / f"uav{i}.csv",
                    1,
                    run,
                    timeout=120,
                    cond=lambda r: r["step"] >= killed_at + SURVIVOR_STEPS,
                )
        # and on until the swarm has found a target (the survivors share what they found)
        survivor = next(i for i in range(m.n_uavs) if i != VICTIM)
        wait_rows(out / f"uav{survivor}.csv", 1, run, timeout=300, cond=lambda r: r["found"] >= 1)
        assert run.stop(timeout=60) in (0, 1), run.text()  # Ctrl-C: the run ends with its report
    finally:
        procs.stop_all()

    # the victim's aircraft: circling the loiter of its trajectory in force, within failsafe_reach
    world = build_world(m)
    radius, reach = world.safety.loiter_radius, world.safety.failsafe_reach
    circling = [p for t, p in track if t > failsafe[0] + 30.0]
    cx, cy, r = fit_circle(circling)
    t_on, point = failsafe
    k = m.kinematics
    plan = m.algorithm.horizon * k.speed * k.step
    farthest = max(math.dist(p, (cx, cy)) for p in circling)
    print(
        f"victim: failsafe {t_on - t_kill:.1f} s after the kill, {math.dist(point, report):.0f} m from its "
        f"last report; circle r {r:.0f} m (loiter {radius:.0f} m), centre "
        f"{math.dist((cx, cy), report):.0f} m from the report; once circling at most {farthest:.0f} m "
        f"from the centre (failsafe_reach {reach:.0f} m)"
    )
    assert math.dist((cx, cy), report) <= plan + 2 * radius, "not the loiter of its trajectory in force"
    assert radius <= r <= FAILSAFE_WIDE * radius, r
    assert farthest <= reach
    assert abs(statistics.median(ups[len(ups) // 2 :]) - m.altitude_of(VICTIM)) < 5.0, "victim off its layer"

    summary = json.loads((out / "summary.json").read_text())["proposed"]
    assert summary["steps"] >= SURVIVOR_STEPS, summary  # the survivors' flight after the kill was scored
    report = out / f"uav{survivor}.json"  # written by the companion on its clean shutdown
    assert report.exists(), (out / f"companion{survivor}.log").read_text()[-3000:]
    found = json.loads(report.read_text())["found_cells"]
    truth = {t["cell"] for t in json.loads((out / "truth.json").read_text())["targets"]}
    assert found and set(found) <= truth, (found, truth)  # the camera's detections of real targets
    tracking = json.loads((out / "tracking.json").read_text())
    assert tracking["outside_fence"] == 0 and tracking["steps"] > 0, tracking
    logs = {i: {int(r["step"]): r for r in read_csv(out / f"uav{i}.csv")} for i in range(m.n_uavs)}
    for i, rows in logs.items():
        flown = list(rows.values())[5:]
        assert flown, f"uav{i} flew no steps"
        assert abs(statistics.median(r["up"] for r in flown) - m.altitude_of(i)) < 5.0, (
            f"uav{i} off its layer"
        )

    # ground truth of separation after the kill, while the survivors flew the mission
    flown_to = min(max(rows) for i, rows in logs.items() if i != VICTIM)
    with (out / "approach.csv").open() as f:
        near = [
            (float(r["distance_m"]), int(r["step"]), int(r["i"]) + int(r["j"]) - VICTIM)
            for r in csv.DictReader(f)
            if VICTIM in (int(r["i"]), int(r["j"])) and killed_at < int(r["step"]) <= flown_to
        ]
    closest = min(near, default=(math.inf, -1, -1))[0]
    print(f"victim: closest approach to a survivor after the kill {closest:.1f} m (R_s {m.comms.safety:g} m)")
    # separation in three dimensions (docs/algorithm.md, "Separation in three dimensions"): a pair
    # closer than R_s horizontally is on layers at least the vertical separation apart, and keeps
    # most of it in flight (each aircraft within ALTITUDE_KEEPING of its layer)
    near_layers = m.near_layers()
    floor = m.vertical_floor
    for d, k, j in near:
        if d <= m.comms.safety:
            assert not near_layers[VICTIM][j], (f"victim and uav{j} share a layer", k, d)
            survivor = logs[j][max(step for step in logs[j] if step <= k)]
            vertical = abs(survivor["up"] - m.altitude_of(VICTIM))
            assert vertical >= floor, (f"victim, uav{j}, step {k}", d, vertical)
    for (i, a), (j, b) in itertools.combinations(logs.items(), 2):
        for k in a.keys() & b.keys():
            if math.dist((a[k]["x"], a[k]["y"]), (b[k]["x"], b[k]["y"])) <= m.comms.safety:
                vertical = abs(a[k]["up"] - b[k]["up"])
                assert vertical >= floor, f"uav{i} and uav{j} at step {k}: {vertical:.0f} m apart"
    # on a shared layer the contingency clause keeps every survivor clear of all the dead UAV's
    # aircraft flies: off its plan until the failsafe fires, onto its loiter, around it
    shared = [d for d, _, j in near if near_layers[VICTIM][j]]
    assert min(shared, default=math.inf) > m.comms.safety, f"the dead UAV's aircraft came {closest:.1f} m"
    # the whole flight, every pair, at the camera's 10 Hz: nothing lost in three dimensions
    approach = out / "approach.csv"
    assert losses_3d(approach, m) == 0, "separation lost in three dimensions"
    print(
        f"uav{VICTIM} and uav{NEIGHBOUR} (adjacent layers, {m.layers.separation:g} m apart; "
        f"partitioned over steps {PARTITION[0]}-{PARTITION[1] - 1}, uav{VICTIM} killed at step {killed_at})"
    )
    phases = {"both alive": range(start, killed_at + 1), "after the kill": range(killed_at + 1, end)}
    for what, steps in phases.items():
        d, k, v = pair_figures(approach, VICTIM, NEIGHBOUR, steps)
        print(
            f"  partitioned, {what}: closest horizontal approach {d:.1f} m (step {k}); least vertical "
            f"separation while within R_s {v:.1f} m (floor {m.vertical_floor:g} m)"
        )


def pair_figures(approach: Path, i: int, j: int, steps: range) -> tuple[float, int, float]:
    """Pair (i, j)'s closest horizontal approach over `steps` of the separation record, its step, and
    the least vertical separation of the pair while within R_s of each other (inf if never)."""
    with approach.open() as f:
        rows = [
            r for r in csv.DictReader(f) if {int(r["i"]), int(r["j"])} == {i, j} and int(r["step"]) in steps
        ]
    if not rows:
        return math.inf, -1, math.inf
    closest = min(rows, key=lambda r: float(r["distance_m"]))
    verticals = [float(r["vertical_m"]) for r in rows if r.get("vertical_m")]
    return float(closest["distance_m"]), int(closest["step"]), min(verticals, default=math.inf)
