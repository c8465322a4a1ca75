"""pymavlink against the PX4 flavour: identity, PX4's parameter names, defaults and integer encoding,
OFFBOARD needing a setpoint stream and leaving for COM_OBL_RC_ACT's mode when it stops, position
setpoints flown to and orbited tightly, DO_REPOSITION in Hold (the change-mode flag, AMSL, the
loiter radius), the geofence (invalid without the vehicle inside, GF_ACTION on a breach)."""

from __future__ import annotations

import struct
import time
from pathlib import Path

import pytest

from tests.sim.conftest import ARRIVED_M, M, Mav, distance_m, offset, write_mission

HOLD = (4 << 16) | (3 << 24)
POSCTL = 3 << 16
ORIGIN_ALT = 584.0  # scenario1's origin, m AMSL


def _stream(mav: Mav, lat: float, lon: float, seconds: float) -> None:
    """Position setpoints at 20 Hz wall (5 Hz simulated at speedup 4)."""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        mav.mav.set_position_target_global_int_send(
            0,
            mav.sysid,
            1,
            M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
            0b110111111000,
            round(lat * 1e7),
            round(lon * 1e7),
            100,
            0,
            0,
            0,
            0,
            0,
            0,
            0,
            0,
        )
        time.sleep(0.05)


def _param(mav: Mav, name: str) -> tuple[float, int]:
    mav.mav.param_request_read_send(mav.sysid, 1, name.encode(), -1)
    msg = mav.need("PARAM_VALUE", lambda m: m.param_id == name)
    return msg.param_value, msg.param_type


def _offboard(mav: Mav, lat: float, lon: float) -> None:
    _stream(mav, lat, lon, 1.0)
    mav.mav.command_long_send(mav.sysid, 1, M.MAV_CMD_DO_SET_MODE, 0, 1, 6, 0, 0, 0, 0, 0)
    _stream(mav, lat, lon, 0.3)
    assert mav.need("COMMAND_ACK", lambda m: m.command == M.MAV_CMD_DO_SET_MODE).result == 0


@pytest.mark.slow
def test_px4_surface(tmp_path: Path, start_sim) -> None:
    path, ports, _ = write_mission(tmp_path, n=2, flavour="px4")
    sim = start_sim(path, "--speedup", "4", "--no-camera", n=2)
    mav = Mav(ports[0], 1)
    hb = mav.need("HEARTBEAT")
    assert (hb.autopilot, hb.custom_mode) == (M.MAV_AUTOPILOT_PX4, 1 << 16)
    assert _param(mav, "FW_AIRSPD_TRIM") == (20.0, M.MAV_PARAM_TYPE_REAL32)
    for name, value in (("NAV_LOITER_RAD", 80.0), ("NAV_ACC_RAD", 10.0), ("COM_OF_LOSS_T", 1.0)):
        assert _param(mav, name)[0] == value, name
    value, kind = _param(mav, "GF_ACTION")  # an INT32, its bytes in the float, as PX4 sends it
    assert kind == M.MAV_PARAM_TYPE_INT32 and struct.unpack("<i", struct.pack("<f", value))[0] == 2
    mav.mav.mission_request_list_send(1, 1, M.MAV_MISSION_TYPE_MISSION)
    assert mav.need("MISSION_COUNT").count == 0
    assert mav.command(M.MAV_CMD_GUIDED_CHANGE_HEADING, 1, 90) == M.MAV_RESULT_UNSUPPORTED
    assert mav.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == 0
    assert mav.command(M.MAV_CMD_DO_SET_MODE, 1, 6) == M.MAV_RESULT_TEMPORARILY_REJECTED
    lat, lon, _ = mav.position()
    tlat, tlon = offset(lat, lon, 500.0, 200.0)
    _offboard(mav, tlat, tlon)
    end = time.monotonic() + 60
    while True:  # flown to, then orbited at the tightest turn (the bank limit: about 50 m here)
        _stream(mav, tlat, tlon, 0.5)
        g = mav.need("GLOBAL_POSITION_INT")
        if distance_m(g.lat * 1e-7, g.lon * 1e-7, tlat, tlon) < 60.0:
            break
        assert time.monotonic() < end, "offboard position setpoint not reached"
    orbit = []
    for _ in range(16):
        _stream(mav, tlat, tlon, 0.5)
        g = mav.need("GLOBAL_POSITION_INT")
        orbit.append(distance_m(g.lat * 1e-7, g.lon * 1e-7, tlat, tlon))
    assert max(orbit) < 70.0, orbit  # tighter than NAV_LOITER_RAD
    # the stream stops: after COM_OF_LOSS_T, COM_OBL_RC_ACT's mode (0: Position mode, straight on)
    assert "Offboard" in mav.need("STATUSTEXT", lambda s: "lost" in s.text).text
    mav.need("HEARTBEAT", lambda m: m.custom_mode == POSCTL)
    # DO_REPOSITION: without the change-mode flag UNSUPPORTED (and not flown outside Hold); with it,
    # Hold, flown to at the AMSL altitude (PX4 reads z as AMSL whatever the frame) and circled at
    # NAV_LOITER_RAD whatever param3 says
    blat, blon = offset(tlat, tlon, -300.0, 300.0)
    args = (blat, blon, ORIGIN_ALT + 120)
    frame = M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
    assert mav.command_int(M.MAV_CMD_DO_REPOSITION, frame, -1, 0, 0, 0, *args) == M.MAV_RESULT_UNSUPPORTED
    assert mav.command_int(M.MAV_CMD_DO_REPOSITION, frame, -1, 1, 30, 0, *args) == 0
    mav.need("HEARTBEAT", lambda m: m.custom_mode == HOLD)
    mav.need(
        "GLOBAL_POSITION_INT",
        lambda g: distance_m(g.lat * 1e-7, g.lon * 1e-7, blat, blon) < ARRIVED_M,
        timeout=60,
    )
    time.sleep(8.0)  # settle on the circle
    radii, ups = [], []
    for _ in range(20):
        g = mav.need("GLOBAL_POSITION_INT")
        radii.append(distance_m(g.lat * 1e-7, g.lon * 1e-7, blat, blon))
        ups.append(g.relative_alt * 1e-3)
        time.sleep(0.2)
    assert abs(sum(radii) / len(radii) - 80.0) < 8.0, radii
    assert ups[-1] > 105.0, ups  # climbing to 120 m above home, not to 120 m AMSL
    # COM_OBL_RC_ACT 5 (an INT32 set as PX4 takes it): losing the stream now means Hold
    five = struct.unpack("<f", struct.pack("<i", 5))[0]
    mav.mav.param_set_send(1, 1, b"COM_OBL_RC_ACT", five, M.MAV_PARAM_TYPE_INT32)
    echo = mav.need("PARAM_VALUE", lambda m: m.param_id == "COM_OBL_RC_ACT")
    assert struct.unpack("<i", struct.pack("<f", echo.param_value))[0] == 5
    _offboard(mav, blat, blon)
    mav.need("HEARTBEAT", lambda m: m.custom_mode == HOLD, timeout=10)
    # a fence without the vehicle in it is ignored, as PX4 does
    other = Mav(ports[1], 2)
    olat, olon, _ = other.position()
    far = [offset(olat, olon, n, e) for n, e in ((1000, 1000), (1000, 1500), (1500, 1500), (1500, 1000))]
    _upload_fence(other, far)
    assert "Geofence invalid" in other.need("STATUSTEXT", lambda s: "Geofence" in s.text).text
    # one around it is in force: flying straight on (Manual), it breaches and holds (GF_ACTION 2)
    near = [offset(olat, olon, n, e) for n, e in ((-300, -300), (-300, 300), (300, 300), (300, -300))]
    _upload_fence(other, near)
    assert other.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == 0
    assert "Geofence violation" in other.need("STATUSTEXT", lambda s: "Geofence" in s.text, timeout=30).text
    other.need("HEARTBEAT", lambda m: m.custom_mode == HOLD)
    rc, _ = sim.stop()
    assert rc == 0
    mav.close()
    other.close()


def _upload_fence(mav: Mav, vertices: list[tuple[float, float]]) -> None:
    n = len(vertices)
    mav.mav.mission_count_send(mav.sysid, 1, n, M.MAV_MISSION_TYPE_FENCE)
    for _ in range(n):
        req = mav.need("MISSION_REQUEST_INT")
        lat, lon = vertices[req.seq]
        mav.mav.mission_item_int_send(
            mav.sysid,
            1,
            req.seq,
            M.MAV_FRAME_GLOBAL,
            M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION,
            0,
            1,
            n,
            0,
            0,
            0,
            round(lat * 1e7),
            round(lon * 1e7),
            0,
            M.MAV_MISSION_TYPE_FENCE,
        )
    assert mav.need("MISSION_ACK").type == M.MAV_MISSION_ACCEPTED
