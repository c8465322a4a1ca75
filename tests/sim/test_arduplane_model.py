"""The simulator's flight models, fence and altitude layers, through MAVLink (pymavlink).

- `sim.dynamics = "kinematic"`: eq. 2 with instant turns, the turn-rate command clipped to the
  turn limit per step;
- the fence (ArduPilot flavour): an uploaded inclusion polygon, enabled, makes a vehicle that
  leaves it report the breach and fly RTL;
- `[layers]`: vehicle i flies its own layer, the band's layers evenly spaced.
"""

from __future__ import annotations

import math
from pathlib import Path

from tests.sim.conftest import M, Mav, distance_m, offset, write_mission

ALTITUDE_STEP = 25.0


def _guided_armed(mav: Mav) -> None:
    assert mav.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_ACCEPTED
    assert mav.command(M.MAV_CMD_DO_SET_MODE, 1, 15) == M.MAV_RESULT_ACCEPTED


def _upload_fence(mav: Mav, corners: list[tuple[float, float]], count: int | None = None) -> int:
    """Upload one inclusion polygon (its items say `count` vertices); the MISSION_ACK result."""
    fence = M.MAV_MISSION_TYPE_FENCE
    mav.mav.mission_count_send(mav.sysid, 1, len(corners), fence)
    for _ in corners:
        req = mav.need("MISSION_REQUEST_INT", lambda r: r.mission_type == fence)
        lat, lon = corners[req.seq]
        mav.mav.mission_item_int_send(
            mav.sysid,
            1,
            req.seq,
            M.MAV_FRAME_GLOBAL,
            M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION,
            0,
            1,
            count or len(corners),
            0,
            0,
            0,
            round(lat * 1e7),
            round(lon * 1e7),
            0,
            fence,
        )
    return mav.need("MISSION_ACK", lambda a: a.mission_type == fence).type


def test_kinematic_model_turns_at_once_within_the_turn_limit(tmp_path: Path, start_sim) -> None:
    path, ports, _ = write_mission(tmp_path, n=1, sim='dynamics = "kinematic"')
    start_sim(path, "--speedup", "10", "--no-camera")
    mav = Mav(ports[0])
    _guided_armed(mav)
    mav.mav.set_attitude_target_send(0, mav.sysid, 1, 195, [1, 0, 0, 0], 0, 0, 0.15, 0)
    mav.need("ATTITUDE", lambda a: abs(a.yawspeed - 0.15) < 1e-6, timeout=5)
    limit = math.radians(45.0) / 2.0  # SIM_TURN_LIMIT per step dT
    mav.mav.set_attitude_target_send(0, mav.sysid, 1, 195, [1, 0, 0, 0], 0, 0, 1.5 * limit, 0)
    mav.need("ATTITUDE", lambda a: abs(a.yawspeed - limit) < 1e-6, timeout=5)
    mav.close()


def test_fence_breach_reports_and_flies_rtl(tmp_path: Path, start_sim) -> None:
    path, ports, _ = write_mission(tmp_path, n=1)
    start_sim(path, "--speedup", "10", "--no-camera")
    mav = Mav(ports[0])
    lat, lon, _ = mav.position()
    square = [offset(lat, lon, n, e) for n, e in ((-300, -300), (-300, 300), (300, 300), (300, -300))]
    assert _upload_fence(mav, square[:2], count=2) == M.MAV_MISSION_INVALID  # not a polygon
    assert _upload_fence(mav, square) == M.MAV_MISSION_ACCEPTED
    mav.mav.mission_request_list_send(mav.sysid, 1, M.MAV_MISSION_TYPE_FENCE)
    assert mav.need("MISSION_COUNT", lambda c: c.mission_type == M.MAV_MISSION_TYPE_FENCE).count == 4
    assert mav.command(M.MAV_CMD_DO_FENCE_ENABLE, 1) == M.MAV_RESULT_ACCEPTED
    mav.mav.param_request_read_send(mav.sysid, 1, b"FENCE_ENABLE", -1)
    assert mav.need("PARAM_VALUE", lambda p: p.param_id == "FENCE_ENABLE").param_value == 1
    _guided_armed(mav)
    assert mav.command(M.MAV_CMD_GUIDED_CHANGE_HEADING, 1, 0, 5) == 0  # north, out of the fence
    text = mav.need("STATUSTEXT", lambda t: "Fence" in t.text, timeout=60)
    assert "breached" in text.text
    mav.need("HEARTBEAT", lambda h: h.custom_mode == 11, timeout=10)  # RTL
    status = mav.need("SYS_STATUS")
    assert status.onboard_control_sensors_enabled & M.MAV_SYS_STATUS_GEOFENCE
    g = mav.need("GLOBAL_POSITION_INT")
    assert distance_m(g.lat * 1e-7, g.lon * 1e-7, lat, lon) > 280  # it was outside when it turned back
    mav.close()


def test_each_vehicle_flies_at_its_altitude_layer(tmp_path: Path, start_sim) -> None:
    path, ports, _ = write_mission(tmp_path, n=3)
    text = path.read_text()
    assert "\naltitude = 100.0" in text
    layers = f"\naltitude = 100.0\n\n[layers]\nband = {2 * ALTITUDE_STEP}\nseparation = {ALTITUDE_STEP}"
    path.write_text(text.replace("\naltitude = 100.0", layers))
    start_sim(path, "--speedup", "10", "--no-camera", n=3)
    for i, port in enumerate(ports):
        mav = Mav(port, sysid=i + 1)
        _guided_armed(mav)
        g = mav.need("GLOBAL_POSITION_INT")
        assert abs(g.relative_alt / 1000 - (100.0 + i * ALTITUDE_STEP)) < 0.01
        mav.close()
