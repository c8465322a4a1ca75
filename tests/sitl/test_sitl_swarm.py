"""A whole swarm on ArduPlane SITL with one command: `uavsearch run --autopilot ardupilot-sitl`.

Four SITL instances (speed-up 4), the stand-alone camera, four companions taking off by themselves
at their altitude layers. One companion is killed mid-mission: its aircraft keeps its last heading
(ArduPlane has no guidance timeout for it) until the fence the companion uploaded (the region plus
its margin) makes the autopilot fly RTL, and then circles home, inside the fence, seen on a ground
station of our own (SITL's SERIAL2). The others fly on; the run, stopped with Ctrl-C, is scored:
targets found, every logged pose inside the fence, each UAV at its altitude layer, and separation:
two UAVs closer than R_s horizontally are apart by their altitude layers (the vertical backstop;
the plan's horizontal separation alone is not kept on a real autopilot, see docs/companion.md).
"""

from __future__ import annotations

import itertools
import json
import math
import os
import signal
import statistics
from pathlib import Path

from companion.node.fence import fence_polygon
from companion.node.frames import LocalFrame
from companion.node.vehicle_link import VehicleLink
from tests.e2e.conftest import PY, Procs, companion_pid, read_csv, wait_rows
from tests.sitl.conftest import GCS_COMPONENT, write_mission

VICTIM = 1
KILL_AFTER = 8  # steps the victim logs before it is killed
SURVIVOR_STEPS = 40  # steps every other UAV logs after the kill
RTL = 11
CIRCLING_S = 40.0  # simulated seconds the victim's aircraft must circle home inside the fence
HOME_M = 200.0  # "circling home": within this of its start (WP_LOITER_RAD 80 m, as ArduPlane flies it)
FLIGHT_S = 400.0  # simulated seconds it gets to reach the fence, turn back and get home


def test_swarm_on_sitl_with_a_companion_killed(sitl_binary: Path, tmp_path: Path) -> None:
    mission = write_mission(tmp_path, 4)
    m = mission.mission
    out = tmp_path / "out"
    procs = Procs(tmp_path)
    argv = [PY, "-m", "companion.app.cli", "run", str(mission.path), "--autopilot", "ardupilot-sitl"]
    argv += ["--speedup", "4", "--steps", "1000", "--out", str(out), "--quiet", "--keep-going"]
    try:
        run = procs.start("run", argv)
        victim_pid = companion_pid(run, VICTIM)
        wait_rows(out / f"uav{VICTIM}.csv", KILL_AFTER, run, timeout=240)
        frame = LocalFrame(m.region.origin)
        ports = mission.ports(VICTIM)
        gcs = VehicleLink(ports.url(ports.serial2), frame, component=GCS_COMPONENT)
        gcs.wait_heartbeat(30)
        gcs.request_streams()
        os.kill(victim_pid, signal.SIGKILL)
        killed_at = int(read_csv(out / f"uav{VICTIM}.csv")[-1]["step"])

        fence = fence_polygon(m)
        home = m.vehicles[VICTIM]
        s = gcs.state
        while not s.has_pose:
            gcs.poll(0.2)
        t_kill, rtl, circling_since = s.time_s, False, None
        while circling_since is None or s.time_s < circling_since + CIRCLING_S:
            gcs.poll(0.1)
            assert s.time_s < t_kill + FLIGHT_S, (
                f"not circling home by t = {s.time_s:.0f} s (RTL seen: {rtl})"
            )
            rtl |= s.custom_mode == RTL
            near = (s.x - home.x) ** 2 + (s.y - home.y) ** 2 <= HOME_M**2
            if circling_since is None and rtl and near:
                circling_since = s.time_s
            elif circling_since is not None:
                assert near and fence.contains(s.x, s.y), f"left home's circle at ({s.x:.0f}, {s.y:.0f})"
        assert s.custom_mode == RTL
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
        assert run.stop(timeout=60) in (0, 1), run.text()  # Ctrl-C: the run ends with its report
    finally:
        procs.stop_all()

    summary = json.loads((out / "summary.json").read_text())["proposed"]
    assert summary["targets_found_fraction"] > 0, summary
    tracking = json.loads((out / "tracking.json").read_text())
    assert tracking["outside_fence"] == 0 and tracking["steps"] > 0, tracking
    logs = {i: {int(r["step"]): r for r in read_csv(out / f"uav{i}.csv")} for i in range(m.n_uavs)}
    for i, rows in logs.items():
        flown = list(rows.values())[5:]
        assert flown, f"uav{i} flew no steps"
        assert abs(statistics.median(r["up"] for r in flown) - m.altitude_of(i)) < 5.0, (
            f"uav{i} off its layer"
        )
    layer = m.kinematics.altitude_step
    for (i, a), (j, b) in itertools.combinations(logs.items(), 2):
        for k in a.keys() & b.keys():
            if math.dist((a[k]["x"], a[k]["y"]), (b[k]["x"], b[k]["y"])) <= m.comms.safety:
                vertical = abs(a[k]["up"] - b[k]["up"])
                assert vertical >= 0.8 * layer * (j - i), (
                    f"uav{i} and uav{j} at step {k}: {vertical:.0f} m apart"
                )
