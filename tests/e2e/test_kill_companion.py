"""Kill -9 one companion mid-mission (`uavsearch run`, scenario1's four UAVs, sped up).

The other three carry on; they forget the dead UAV within a few steps (their `peers` count drops
from 3 to 2), so its task is no longer held by anyone in their views and goes back to the auction;
and the mission still ends with a report. The dead companion's vehicle, without its HEARTBEATs, flies
on for `safety.failsafe_timeout` (one step here), then the autopilot's GCS failsafe (which the
companion armed with --takeover, and kept on the loiter of its trajectory in force every step)
switches it to AUTO and it circles that loiter (seen on our own MAVLink connection), within
`safety.failsafe_reach` of its centre, as the survivors' model of a silent UAV assumes. The
simulator's physics-rate record (approach.csv) gives its closest approach to a survivor after the
kill, which is never within R_s of a survivor on a near layer, nor within R_s and vertically
closer than the layers keep of one on a layer apart (docs/algorithm.md, "A silent UAV stays an obstacle": the
contingency clause keeps every survivor clear of all the dead UAV's aircraft flies, off its plan
until the failsafe fires, onto its loiter and around it).
"""

from __future__ import annotations

import csv
import json
import math
import os
import signal
from pathlib import Path

from companion.contracts.frames import LocalFrame
from companion.core.world import FAILSAFE_WIDE, build_world
from tests.e2e.conftest import PY, Procs, companion_pid, read_csv, wait_rows, wait_vehicles
from tests.sim.conftest import fit_circle

STEPS = 80
KILL_AFTER = 15  # steps logged by the victim before it is killed
VICTIM = 2
AUTO = 10
SPEEDUP = 4
FAILSAFE_TIMEOUT_S = 2.0  # FS_LONG_TIMEOUT (one step): 0.5 s of wall time at SPEEDUP


def test_kill_one_companion_mid_mission(make_mission, procs: Procs, ground, tmp_path: Path) -> None:
    mission = make_mission(n=4, safety=f"failsafe_timeout = {FAILSAFE_TIMEOUT_S}")
    m = mission.mission
    out = tmp_path / "out"
    run = procs.start(
        "run",
        [
            PY,
            "-m",
            "companion.cli",
            "run",
            str(mission.path),
            "--speedup",
            str(SPEEDUP),
            "--steps",
            str(STEPS),
            "--out",
            str(out),
            "--quiet",
            "--keep-going",
        ],
    )
    victim_pid = companion_pid(run, VICTIM)
    wait_vehicles(run, out, m.n_uavs)
    gcs = ground(mission.ports[VICTIM], VICTIM + 1)
    wait_rows(out / f"uav{VICTIM}.csv", KILL_AFTER, run)
    assert "failsafe armed" in (out / f"companion{VICTIM}.log").read_text()

    os.kill(victim_pid, signal.SIGKILL)
    rows = read_csv(out / f"uav{VICTIM}.csv")
    kill_step = int(rows[-1]["step"])
    report = (rows[-1]["x"], rows[-1]["y"])  # its last report: its pose at the start of its last step

    # its vehicle: the failsafe fires, then it circles where it is, until the run ends
    frame = LocalFrame(m.region.origin)
    track: list[tuple[float, tuple[float, float]]] = []
    failsafe_at: tuple[float, float] | None = None
    modes = set()
    while run.alive():
        msg = gcs.wait(["GLOBAL_POSITION_INT", "STATUSTEXT", "HEARTBEAT"], timeout=2.0)
        if msg is None:
            continue
        kind = msg.get_type()
        if kind == "GLOBAL_POSITION_INT":
            track.append((msg.time_boot_ms * 1e-3, frame.to_local(msg.lat * 1e-7, msg.lon * 1e-7)))
        elif kind == "STATUSTEXT" and msg.text == "GCS Failsafe On: AUTO" and track:
            failsafe_at = track[-1][1]
        elif kind == "HEARTBEAT" and msg.get_srcComponent() == 1:
            modes.add(msg.custom_mode)
    assert run.popen.returncode in (0, 1), run.text()  # 1: pass criteria not met in so short a mission
    assert failsafe_at is not None and AUTO in modes, f"no failsafe seen (modes {modes})"
    world = build_world(m)
    t_on = next(t for t, p in track if p == failsafe_at)
    circling = [p for t, p in track if t > t_on + 30.0]
    assert len(circling) > 100, "the run ended too soon after the failsafe"
    cx, cy, r = fit_circle(circling)
    radius, reach = world.safety.loiter_radius, world.safety.failsafe_reach
    k = m.kinematics
    plan = m.algorithm.horizon * k.speed * k.step  # the loiter of a trajectory in force from its report
    entry = max(math.dist(p, (cx, cy)) for t, p in track if t > t_on)
    print(
        f"victim: failsafe {math.dist(failsafe_at, report):.0f} m from its last report; circle r {r:.0f} m "
        f"(loiter {radius:.0f} m), centre {math.dist((cx, cy), report):.0f} m from the report; farthest "
        f"from the centre after the failsafe {entry:.0f} m, once on the circle "
        f"{max(math.dist(p, (cx, cy)) for p in circling):.0f} m (failsafe_reach {reach:.0f} m)"
    )
    assert math.dist((cx, cy), report) <= plan + 2 * radius, "not the loiter of its trajectory in force"
    assert radius <= r <= FAILSAFE_WIDE * radius, (cx, cy, r)
    assert max(math.dist(p, (cx, cy)) for p in circling) <= reach

    # ground truth of separation after the kill, while the survivors flew the mission (their
    # companions stop at the step budget): the victim's closest approach to a survivor
    survivors = [i for i in range(m.n_uavs) if i != VICTIM]
    logs = {i: {int(r["step"]): r for r in read_csv(out / f"uav{i}.csv")} for i in survivors}
    flown_to = min(max(rows_i) for rows_i in logs.values())
    with (out / "approach.csv").open() as f:
        record = [r for r in csv.DictReader(f) if kill_step < int(r["step"]) <= flown_to]
    assert len({r["step"] for r in record}) >= flown_to - kill_step - 1, "steps missing in approach.csv"
    near = [r for r in record if VICTIM in (int(r["i"]), int(r["j"]))]  # pairs within 3 R_s (and closest)
    closest = min((float(r["distance_m"]) for r in near), default=math.inf)
    print(f"victim: closest approach to a survivor after the kill {closest:.1f} m (R_s {m.comms.safety:g} m)")

    # the others carried on well past the kill
    timeout = m.comms.peer_timeout_steps
    for i, rows_i in logs.items():
        assert max(rows_i) >= kill_step + 40, f"uav{i} stopped at step {max(rows_i)} (kill at {kill_step})"
        assert len(rows_i) >= STEPS - 2
        # before the kill it knew all three others (directly or through relayed claims) ...
        before = [rows_i[k]["peers"] for k in range(kill_step - 4, kill_step + 1) if k in rows_i]
        assert before and max(before) == 3, f"uav{i} peers before the kill: {before}"
        # ... and within a few steps of it, only the two survivors: the dead UAV and its task are gone
        forgotten = kill_step + timeout + 4
        after = [(k, r["peers"]) for k, r in rows_i.items() if k >= forgotten]
        assert after and all(p <= 2 for _, p in after), f"uav{i} still counts the dead UAV: {after[:10]}"
        assert all(r["steered"] for k, r in rows_i.items() if k > kill_step), f"uav{i} stopped steering"

    # the mission ended with a report of the whole run
    summary = json.loads((out / "summary.json").read_text())
    assert summary["proposed"]["runs"] == 1
    assert json.loads((out / "criteria.json").read_text()).keys() >= {"passed", "failures"}
    with (out / "trajectories.csv").open() as f:  # steps from the first one every UAV logged
        flown = {int(r["step"]) for r in csv.DictReader(f)}
    assert len(flown) >= STEPS - 2
    for i in survivors:
        assert json.loads((out / f"uav{i}.json").read_text())["steps"] >= STEPS - 2
    assert not (out / f"uav{VICTIM}.json").exists()  # killed: no clean-shutdown report of its own
    live = [float(r["distance_m"]) for r in record if VICTIM not in (int(r["i"]), int(r["j"]))]
    assert min(live, default=math.inf) > m.comms.safety, "two survivors came within R_s"
    # separation in three dimensions: the dead UAV's aircraft is never within R_s of a survivor on
    # a near layer, and one on a layer apart stays vertically apart when within R_s
    shared = m.near_layers()
    for r in near:
        survivor = int(r["i"]) + int(r["j"]) - VICTIM
        if float(r["distance_m"]) <= m.comms.safety:
            assert not shared[VICTIM][survivor], f"the dead UAV's aircraft came within R_s: {r}"
            assert float(r["vertical_m"]) >= m.vertical_floor, f"3D separation lost: {r}"
