"""A ground station (MAVProxy, headless) attached to a vehicle while its companion flies it.

MAVProxy connects to vehicle 0's endpoint next to the companion: it sees the vehicle (heartbeats,
GUIDED, armed), downloads its parameters, and logs it all; meanwhile the companion keeps steering
and the vehicle keeps following its commands.
"""

from __future__ import annotations

import sys
from pathlib import Path

from pymavlink import mavutil

from sim_vehicles.protocols.params import param_specs
from tests.e2e.conftest import GUIDED, Procs, assert_follows, read_csv, wait_rows

MAVPROXY = str(Path(sys.executable).parent / "mavproxy.py")  # installed with the test extras
WITH_GCS_STEPS = 25  # steps flown with MAVProxy attached
GCS_WAIT_S = 300.0  # generous: MAVProxy starts and downloads the parameters slowly on a busy machine


def test_mavproxy_attached_while_the_companion_flies(make_mission, procs: Procs, tmp_path: Path) -> None:
    mission = make_mission(n=1)
    k = mission.mission.kinematics
    out = tmp_path / "out"
    procs.sim(mission, "--speedup", "10")
    comp = procs.companion(mission, 0, out, "--takeover", "--command-mode", "turn-rate", "--steps", "5000")
    csv_path = out / "uav0.csv"
    wait_rows(csv_path, 5, comp, cond=lambda r: r["steered"] == 1)

    gcs_dir = tmp_path / "mavproxy"
    gcs_dir.mkdir()
    tlog = gcs_dir / "gcs.tlog"
    proxy = procs.start(
        "mavproxy",
        [
            MAVPROXY,
            f"--master=udpout:127.0.0.1:{mission.ports[0]}",
            "--daemon",
            "--state-basedir",
            str(gcs_dir),
            "--logfile",
            str(tlog),
        ],
        cwd=gcs_dir,
    )
    ardupilot_params = sum(p.ardupilot is not None for p in param_specs(mission.mission))
    proxy.wait_for_text(f"Received {ardupilot_params} parameters", timeout=GCS_WAIT_S)
    proxy.wait_for_text("Mode GUIDED", timeout=GCS_WAIT_S)
    attached = int(read_csv(csv_path)[-1]["step"])
    wait_rows(csv_path, WITH_GCS_STEPS, comp, timeout=GCS_WAIT_S, cond=lambda r: r["step"] > attached)
    assert proxy.alive(), proxy.text()
    rc = proxy.stop(timeout=15)
    text = proxy.text()
    assert "Traceback" not in text, text

    # what MAVProxy received: the vehicle's heartbeats in GUIDED, armed, and its parameters
    log = mavutil.mavlink_connection(str(tlog))
    beats = params = 0
    while (msg := log.recv_match(type=["HEARTBEAT", "PARAM_VALUE"])) is not None:
        if msg.get_srcSystem() != 1:
            continue
        if msg.get_type() == "PARAM_VALUE":
            params += 1
        elif msg.get_srcComponent() == 1 and msg.custom_mode == GUIDED:
            beats += (msg.base_mode & mavutil.mavlink.MAV_MODE_FLAG_SAFETY_ARMED) != 0
    assert beats >= 3 and params >= 5, (beats, params, rc, text)

    # the companion kept steering while the ground station was attached, and the vehicle followed
    assert comp.alive(), comp.text()
    rows = [r for r in read_csv(csv_path) if r["step"] > attached]
    assert len(rows) >= WITH_GCS_STEPS
    assert all(r["steered"] == 1 for r in rows), "the companion stopped steering"
    assert_follows(rows, k.speed, k.step, "turn-rate with MAVProxy attached", skip=0)
    assert comp.stop() == 0, comp.text()
