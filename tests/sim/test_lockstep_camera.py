"""Lockstep (grid kinematics): time advances only when every vehicle is ready, poses match
`Kinematics.advance` exactly, and the camera frames received over a real Zenoh session match the
ground truth the simulator wrote."""

from __future__ import annotations

import json
import math
import threading
from pathlib import Path

import numpy as np
import zenoh

from companion.contracts import detections
from companion.core.feasibility import load_mission
from companion.core.kinematics import Kinematics
from sim_vehicles.camera import draw_truth
from tests.sim.conftest import M, Mav, free_tcp_port, write_mission

DT = 2.0
EIGHTH = math.pi / 4


def _ready(mav: Mav, step: int) -> None:
    assert mav.command(31010, step) == M.MAV_RESULT_ACCEPTED


def _snapshot(mav: Mav, step: int) -> tuple[object, object]:
    """(LOCAL_POSITION_NED, ATTITUDE) of a step; LOCAL_POSITION_NED comes last."""
    got: dict[str, object] = {}
    while "LOCAL_POSITION_NED" not in got:
        m = mav.need(["ATTITUDE", "LOCAL_POSITION_NED"], lambda m: m.time_boot_ms == round(step * DT * 1000))
        got[m.get_type()] = m
    return got["LOCAL_POSITION_NED"], got["ATTITUDE"]


def test_lockstep_grid_and_camera(tmp_path: Path, start_sim) -> None:
    probe, _, _ = write_mission(tmp_path, n=2, mode="grid")
    grid, targets = draw_truth(load_mission(probe), 1)
    tx, ty = grid.centres[targets[0]]  # vehicle 0 starts on a target, so frames are not all empty
    zport = free_tcp_port()
    path, ports, prefix = write_mission(tmp_path, n=2, mode="grid", starts=[(tx, ty), (tx + 400, -900.0)])
    mission = load_mission(path)
    frames: list[detections.CameraFrame] = []
    lock = threading.Lock()
    cfg = {
        "mode": "peer",
        "listen": {"endpoints": [f"tcp/127.0.0.1:{zport}"]},
        "scouting": {"multicast": {"enabled": False}},
    }
    with zenoh.open(zenoh.Config.from_json5(json.dumps(cfg))) as session:

        def on_sample(sample: zenoh.Sample) -> None:
            with lock:
                frames.append(detections.decode_checked(sample.payload.to_bytes(), 2))

        session.declare_subscriber(f"{prefix}/{mission.name}/uav/*/camera", on_sample)
        truth_path = tmp_path / "truth.json"
        sim = start_sim(
            path, "--lockstep", "--truth", str(truth_path), "--zenoh-connect", f"tcp/127.0.0.1:{zport}", n=2
        )
        a, b = Mav(ports[0], 1), Mav(ports[1], 2)
        truth = json.loads(truth_path.read_text())
        assert [t["cell"] for t in truth["targets"]] == targets.tolist()
        for mav in (a, b):
            assert mav.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == 0
            assert mav.command(M.MAV_CMD_DO_SET_MODE, 1, 15) == 0
            _ready(mav, 0)  # snapshot of step 0
            _snapshot(mav, 0)
        assert a.command(31010, 5) == M.MAV_RESULT_DENIED  # cannot skip ahead
        kin = Kinematics("grid", 20.0, DT, EIGHTH, 40.0)
        poses = np.array([(v.x, v.y, math.radians(v.heading_deg)) for v in mission.vehicles])
        turns = [[0, 1, 1, 0, -1, -1, 0, 0], [1, 0, -1, 0, 2, 0, 0, -1]]  # in 45 degree units
        for k in range(len(turns[0])):
            for i, mav in enumerate((a, b)):
                turn = turns[i][k] * EIGHTH
                mav.mav.set_attitude_target_send(0, mav.sysid, 1, 195, [1, 0, 0, 0], 0, 0, -turn / DT, 0)
            _ready(a, k + 1)
            if k == 0:  # b has not reported: time stands still
                assert a.wait("LOCAL_POSITION_NED", lambda m: m.time_boot_ms > 0, timeout=1.5) is None
            _ready(b, k + 1)
            q = np.clip(np.array([turns[0][k], turns[1][k]]), -1, 1) * EIGHTH
            x, y, h = kin.advance(poses[:, 0], poses[:, 1], poses[:, 2], q)
            poses = np.column_stack([x, y, h])
            for i, mav in enumerate((a, b)):
                ned, att = _snapshot(mav, k + 1)
                assert abs(ned.y - poses[i, 0]) < 1e-3 and abs(ned.x - poses[i, 1]) < 1e-3
                yaw = (math.pi / 2 - poses[i, 2] + math.pi) % (2 * math.pi) - math.pi
                assert abs(math.remainder(att.yaw - yaw, 2 * math.pi)) < 1e-5
        assert sim.proc.poll() is None
        rc, _ = sim.stop()
        assert rc == 0
        a.close()
        b.close()
    with lock:
        got = list(frames)
    steps = len(turns[0])
    per_uav = {i: sorted(f.time_usec for f in got if f.uav == i) for i in (0, 1)}
    for i in (0, 1):  # one frame per snapshot: step 0 and every advance
        assert set(range(0, int((steps + 1) * DT * 1e6), int(DT * 1e6))) <= set(per_uav[i])
    seen_any = False
    target_ll = {(t["lat"], t["lon"]): (t["x"], t["y"]) for t in truth["targets"]}
    for f in got:
        assert set(f.detections) <= set(target_ll)
        fx, fy = _local_of(mission, f)
        expected = {ll for ll, (x, y) in target_ll.items() if (x - fx) ** 2 + (y - fy) ** 2 <= 60.0**2 + 1e-6}
        assert set(f.detections) == expected
        seen_any |= bool(f.detections)
    assert seen_any


def _local_of(mission, frame: detections.CameraFrame) -> tuple[float, float]:
    from companion.contracts.frames import LocalFrame

    x, y = LocalFrame(mission.region.origin).to_local(frame.lat, frame.lon)
    return round(x / 20) * 20, round(y / 20) * 20  # on the grid at every step boundary
