"""A whole swarm on ArduPlane SITL with one command: `uavsearch run --autopilot ardupilot-sitl`.

The mission is the no-fly example's area (scenario1_nofly: a no-fly band across scenario 1's middle,
from the operator's .plan). Four SITL instances (speed-up 4, ADS-B on as the run sets it), the
stand-alone camera, four companions taking off by themselves at their altitude layers (one each),
each arming its autopilot's failsafe for its own silence and keeping it on the loiter of its
trajectory in force. UAV 1 starts 140 m from UAV 2, on the layer next to it. A radio partition ({0,
1} against {2, 3}, the fault matrix's partition row) cuts that pair apart while both are in range,
and UAV 1's companion is then killed mid-partition: its aircraft flies its last guidance for
`safety.failsafe_timeout` (one step, the default), then ArduPlane's GCS failsafe switches it to AUTO
and it circles that loiter (seen on a ground station of our own, SITL's SERIAL2), within
`safety.failsafe_reach` of the loiter's centre. The others fly on; the run, stopped with Ctrl-C, is
scored: targets found, every logged pose inside the fence, each UAV at its altitude layer (from its
first steered step on), and separation in three dimensions (docs/algorithm.md, "Separation in three
dimensions"): in the camera's record of every pair's closest approach (approach.csv, from the
vehicles' position streams at 10 Hz, with their altitudes) no two aircraft are within R_s
horizontally and closer vertically than the layers' floor, at any time; and no logged pose entered
the band inflated by `safety.margin` (criteria.json; the survivors fly on until one works at the
band's side). MAVProxy on survivor uav2's SERIAL2, while the swarm flies, sees the companion's
progress values and HEARTBEAT, the peers as ArduPlane's own ADSB_VEHICLE traffic and, for a target
found while it watches, the detection's STATUSTEXT; the fence read back there by plain pymavlink is
the mission's, the band as the .plan draws it.
"""

from __future__ import annotations

import csv
import itertools
import json
import math
import os
import re
import signal
import statistics
import time
from pathlib import Path

import shapely
from pymavlink import mavutil

from companion.app.evaluation import losses_3d
from companion.contracts.frames import LocalFrame
from companion.contracts.mission import Mission
from companion.core.search_area import zone_shape
from companion.core.world import FAILSAFE_WIDE, build_world
from companion.node.vehicle_link import COMPANION_SYSTEM, VehicleLink
from tests.e2e.conftest import (
    PY,
    SCENARIO1_NOFLY,
    Proc,
    Procs,
    assert_at_layer_while_steered,
    companion_pid,
    mavproxy_argv,
    read_csv,
    wait_rows,
)
from tests.fence_readback import assert_exclusions_as_drawn, companion_fence, read_fence
from tests.sim.conftest import fit_circle
from tests.sitl.conftest import GCS_COMPONENT, STARTUP_S, write_mission

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
WATCHER = 2  # MAVProxy on its SERIAL2: a survivor with a peer (uav3) throughout the partition
AFTER_FOUND = 3  # steps the watcher logs after its first target before MAVProxy is stopped
NEAR_ZONE_S = 300.0  # generous: wall seconds for the survivors to reach the band's side
TEXT = re.compile(r"UAV(\d+) target at (-?\d+\.\d+) (-?\d+\.\d+)")


def test_swarm_on_sitl_with_a_companion_killed(sitl_binary: Path, tmp_path: Path) -> None:
    start, end = PARTITION
    partition = f"\n[[faults.network]]\nstart = {start}\nend = {end}\ngroups = [[0, 1], [2, 3]]\n"
    safety = f"failsafe_timeout = {FAILSAFE_TIMEOUT_S}"
    mission = write_mission(tmp_path, 4, starts=STARTS, safety=safety, extra=partition, base=SCENARIO1_NOFLY)
    m = mission.mission
    assert len(m.region.nofly) == 1
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
        watched = mission.ports(WATCHER)
        argv, tlog = mavproxy_argv(watched.url(watched.serial2), tmp_path / "mavproxy")
        proxy = procs.start("mavproxy", argv, cwd=tlog.parent)
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
        proxy.wait_for_text("Mode ", timeout=STARTUP_S)  # it hears the watcher's autopilot
        for i in range(m.n_uavs):
            if i != VICTIM:
                wait_rows(
                    out / f"uav{i}.csv",
                    1,
                    run,
                    timeout=120,
                    cond=lambda r: r["step"] >= killed_at + SURVIVOR_STEPS,
                )
        # and on until the swarm has found a target (the survivors share what they found), and a
        # few steps more for MAVProxy to hear the watcher's report of it
        survivor = WATCHER
        wait_rows(out / f"uav{survivor}.csv", 1, run, timeout=300, cond=lambda r: r["found"] >= 1)
        found_at = next(int(r["step"]) for r in read_csv(out / f"uav{survivor}.csv") if r["found"] >= 1)
        wait_rows(
            out / f"uav{survivor}.csv",
            1,
            run,
            timeout=120,
            cond=lambda r: r["step"] >= found_at + AFTER_FOUND,
        )
        assert proxy.alive(), proxy.text()
        proxy.stop(timeout=15)
        assert "Traceback" not in proxy.text(), proxy.text()
        # MAVProxy gone, SERIAL2 is free: the watcher's fence, read by plain pymavlink
        conn = mavutil.mavlink_connection(
            watched.url(watched.serial2), source_system=250, dialect="ardupilotmega"
        )
        try:
            fence = read_fence(conn, WATCHER + 1)
        finally:
            conn.close()
        # and on until a survivor works at the band's side: within the keep-out's margin, a failsafe
        # region (its plans keep theirs clear of the keep-out) and a step (two runs: 217-234 m)
        near = m.safety.margin + build_world(m).safety.failsafe_reach + m.kinematics.speed * m.kinematics.step
        wait_near_zones(m, out, run, [i for i in range(m.n_uavs) if i != VICTIM], near)
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

    # the no-fly band: in the autopilot's fence as drawn, and never entered by a logged pose
    assert fence == companion_fence(m), fence
    assert_exclusions_as_drawn(fence, SCENARIO1_NOFLY.parent / m.region.area)
    criteria = json.loads((out / "criteria.json").read_text())
    assert criteria["passed"] or not [f for f in criteria["failures"] if "no-fly" in f], criteria
    nearest = closest_to_zones(m, logs)
    print(f"closest logged pose to the no-fly band: {nearest:.0f} m (safety.margin {m.safety.margin:g} m)")
    assert nearest > 0.0, "a logged pose inside the no-fly band"
    assert_ground_station_saw(tlog, m, out, WATCHER)
    for i, rows in logs.items():
        flown = list(rows.values())[5:]
        assert flown, f"uav{i} flew no steps"
        assert abs(statistics.median(r["up"] for r in flown) - m.altitude_of(i)) < 5.0, (
            f"uav{i} off its layer"
        )
        assert_at_layer_while_steered(m, i, rows)

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


def closest_to_zones(m: Mission, logs: dict[int, dict[int, dict[str, float]]]) -> float:
    """The least distance of any logged pose to a no-fly zone (0 inside one)."""
    zones = shapely.union_all([zone_shape(z) for z in m.region.nofly])
    return min(zones.distance(shapely.Point(r["x"], r["y"])) for rows in logs.values() for r in rows.values())


def wait_near_zones(m: Mission, out: Path, run: Proc, uavs: list[int], within: float) -> None:
    """Wait (generously) until one of `uavs` has logged a pose within `within` m of a no-fly zone."""
    deadline = time.monotonic() + NEAR_ZONE_S
    while True:
        logs = {i: {int(r["step"]): r for r in read_csv(out / f"uav{i}.csv")} for i in uavs}
        if closest_to_zones(m, logs) <= within:
            return
        assert run.alive(), run.text()
        assert time.monotonic() < deadline, f"no UAV came within {within:g} m of a no-fly zone"
        time.sleep(1.0)


def assert_ground_station_saw(tlog: Path, m: Mission, out: Path, watched: int) -> None:
    """MAVProxy's .tlog on uav `watched`'s SERIAL2: the companion's progress values and HEARTBEAT,
    the peers as ArduPlane's own ADSB_VEHICLEs where they logged themselves, and a STATUSTEXT at a
    real target's cell if the companion learnt of a target while MAVProxy listened."""
    seen: dict[tuple[int, str], list] = {}
    log = mavutil.mavlink_connection(str(tlog))
    while (msg := log.recv_match()) is not None:
        seen.setdefault((msg.get_srcSystem(), msg.get_type()), []).append(msg)
    values: dict[str, list[float]] = {}
    for v in seen.get((COMPANION_SYSTEM, "NAMED_VALUE_FLOAT"), []):
        values.setdefault(v.name, []).append(v.value)
    assert set(values) == {"coverage", "mean_eta", "found", "p_unfound", "cpu_pct"}, sorted(seen)
    assert max(values["found"]) >= 1 and 0 < max(values["coverage"]) <= 1, values["found"]
    beats = seen[(COMPANION_SYSTEM, "HEARTBEAT")]
    assert any(b.system_status == mavutil.mavlink.MAV_STATE_ACTIVE for b in beats), len(beats)
    # ADS-B on: the peers are ArduPlane's traffic (system watched + 1), none routed from system 200
    assert (COMPANION_SYSTEM, "ADSB_VEHICLE") not in seen
    traffic = [a for a in seen.get((watched + 1, "ADSB_VEHICLE"), []) if a.callsign.startswith("UAV")]
    assert traffic, f"no peer in ArduPlane's traffic: {len(seen.get((watched + 1, 'ADSB_VEHICLE'), []))}"
    frame = LocalFrame(m.region.origin)
    rows = {j: read_csv(out / f"uav{j}.csv") for j in range(m.n_uavs)}
    for a in traffic:
        j = int(a.callsign[3:])
        assert j != watched and abs(a.altitude * 1e-3 - m.region.origin.alt - m.altitude_of(j)) < 0.01, a
        x, y = frame.to_local(a.lat * 1e-7, a.lon * 1e-7)
        assert min(math.hypot(x - r["x"], y - r["y"]) for r in rows[j]) < 1.0, (a.callsign, x, y)
    print(
        f"MAVProxy on uav{watched}: traffic {sorted({a.callsign for a in traffic})}, "
        f"found {values['found'][0]:g} to {max(values['found']):g}"
    )
    texts = [t for t in seen.get((COMPANION_SYSTEM, "STATUSTEXT"), []) if TEXT.fullmatch(t.text)]
    if values["found"][0] < max(values["found"]):  # a target learnt while MAVProxy listened
        assert texts, "no detection's STATUSTEXT"
    world = build_world(m)
    truth = [t["cell"] for t in json.loads((out / "truth.json").read_text())["targets"]]
    cells = [frame.to_geodetic(*map(float, world.grid.centres[c]))[:2] for c in truth]
    for t in texts:
        said = TEXT.fullmatch(t.text)
        lat, lon = float(said[2]), float(said[3])
        assert any(abs(lat - a) < 2e-6 and abs(lon - b) < 2e-6 for a, b in cells), t.text
