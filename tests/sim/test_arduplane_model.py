"""The simulator's flight models, fence and altitude layers, through MAVLink (pymavlink).

- `sim.dynamics = "kinematic"`: eq. 2 with instant turns, the turn-rate command clipped to the
  turn limit per step;
- the fence (ArduPilot flavour): an uploaded inclusion polygon, enabled, makes a vehicle that
  leaves it report the breach and fly RTL; so does an exclusion polygon or circle that it enters,
  and the fence reads back (MISSION_REQUEST_LIST, MISSION_REQUEST_INT) as uploaded;
- `[layers]`: vehicle i flies its own layer, the band's layers evenly spaced.
"""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from tests.sim.conftest import M, Mav, distance_m, offset, write_mission

ALTITUDE_STEP = 25.0


def _guided_armed(mav: Mav) -> None:
    assert mav.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_ACCEPTED
    assert mav.command(M.MAV_CMD_DO_SET_MODE, 1, 15) == M.MAV_RESULT_ACCEPTED


FenceItem = tuple[int, float, int, int]  # command, param1 (vertex count or radius), lat and lon * 1e7


def _polygon(corners: list[tuple[float, float]], command: int, count: int | None = None) -> list[FenceItem]:
    """A fence polygon's items (they say `count` vertices, default as many as there are)."""
    return [(command, count or len(corners), round(lat * 1e7), round(lon * 1e7)) for lat, lon in corners]


def _upload_fence(mav: Mav, corners: list[tuple[float, float]], count: int | None = None) -> int:
    """Upload one inclusion polygon (its items say `count` vertices); the MISSION_ACK result."""
    return _upload(mav, _polygon(corners, M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION, count))


def _upload(mav: Mav, items: list[FenceItem]) -> int:
    """Upload a fence's items; the MISSION_ACK result."""
    fence = M.MAV_MISSION_TYPE_FENCE
    mav.mav.mission_count_send(mav.sysid, 1, len(items), fence)
    for _ in items:
        req = mav.need("MISSION_REQUEST_INT", lambda r: r.mission_type == fence)
        command, param1, x, y = items[req.seq]
        mav.mav.mission_item_int_send(
            mav.sysid, 1, req.seq, M.MAV_FRAME_GLOBAL, command, 0, 1, param1, 0, 0, 0, x, y, 0, fence
        )
    return mav.need("MISSION_ACK", lambda a: a.mission_type == fence).type


def _download(mav: Mav) -> list[FenceItem]:
    """The vehicle's fence, read back with the mission protocol."""
    fence = M.MAV_MISSION_TYPE_FENCE
    mav.mav.mission_request_list_send(mav.sysid, 1, fence)
    count = mav.need("MISSION_COUNT", lambda c: c.mission_type == fence).count
    out = []
    for seq in range(count):
        mav.mav.mission_request_int_send(mav.sysid, 1, seq, fence)
        it = mav.need("MISSION_ITEM_INT", lambda m, s=seq: m.seq == s and m.mission_type == fence)
        out.append((it.command, it.param1, it.x, it.y))
    mav.mav.mission_ack_send(mav.sysid, 1, M.MAV_MISSION_ACCEPTED, fence)
    return out


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


@pytest.mark.parametrize("zone", ["polygon", "circle"])
def test_entering_an_exclusion_zone_breaches_the_fence(tmp_path: Path, start_sim, zone: str) -> None:
    path, ports, _ = write_mission(tmp_path, n=1)
    start_sim(path, "--speedup", "10", "--no-camera")
    mav = Mav(ports[0])
    lat, lon, _ = mav.position()
    big = [offset(lat, lon, n, e) for n, e in ((-3000, -3000), (-3000, 3000), (3000, 3000), (3000, -3000))]
    items = _polygon(big, M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION)
    if zone == "polygon":  # a band 300 m to 500 m north, not convex (a notch in its south side)
        band = [(300, -400), (300, 400), (500, 400), (500, -400), (400, -300)]
        corners = [offset(lat, lon, n, e) for n, e in band]
        items += _polygon(corners, M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION)
    else:  # a circle of radius 150 m centred 450 m north
        clat, clon = offset(lat, lon, 450, 0)
        items.append((M.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION, 150.0, round(clat * 1e7), round(clon * 1e7)))
        bad = (M.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION, 0.0, round(clat * 1e7), round(clon * 1e7))
        assert _upload(mav, [*items[:4], bad]) == M.MAV_MISSION_INVALID  # no radius
    assert _upload(mav, items) == M.MAV_MISSION_ACCEPTED
    assert _download(mav) == items
    assert mav.command(M.MAV_CMD_DO_FENCE_ENABLE, 1) == M.MAV_RESULT_ACCEPTED
    _guided_armed(mav)
    assert mav.command(M.MAV_CMD_GUIDED_CHANGE_HEADING, 1, 0, 5) == 0  # north, into the zone
    text = mav.need("STATUSTEXT", lambda t: "Fence" in t.text, timeout=60)
    assert "breached" in text.text
    fence = M.MAV_SYS_STATUS_GEOFENCE
    status = mav.need("SYS_STATUS", lambda s: not s.onboard_control_sensors_health & fence)  # breached
    assert status.onboard_control_sensors_enabled & fence
    g = mav.need("GLOBAL_POSITION_INT")
    assert distance_m(g.lat * 1e-7, g.lon * 1e-7, lat, lon) > 280  # it breached at the zone, not before
    mav.need("HEARTBEAT", lambda h: h.custom_mode == 11, timeout=10)  # RTL
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
