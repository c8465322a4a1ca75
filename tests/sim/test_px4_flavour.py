"""pymavlink against the PX4 flavour: identity, OFFBOARD needing a setpoint stream and falling
back when it stops, position setpoints flown, DO_REPOSITION in Hold, PX4 parameter names."""

from __future__ import annotations

import time
from pathlib import Path

from tests.sim.conftest import ARRIVED_M, M, Mav, distance_m, offset, write_mission

HOLD = (4 << 16) | (3 << 24)
OFFBOARD = 6 << 16


def _stream(mav: Mav, lat: float, lon: float, seconds: float) -> None:
    """Position setpoints at 20 Hz wall (10 Hz simulated at speedup 2)."""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        mav.mav.set_position_target_global_int_send(
            0, mav.sysid, 1, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, 0b110111111000,
            round(lat * 1e7), round(lon * 1e7), 100, 0, 0, 0, 0, 0, 0, 0, 0)
        time.sleep(0.05)


def test_px4_surface(tmp_path: Path, start_sim) -> None:
    path, ports, _ = write_mission(tmp_path, n=2, flavour="px4")
    sim = start_sim(path, "--speedup", "2", "--no-camera", n=2)
    mav = Mav(ports[0], 1)
    hb = mav.need("HEARTBEAT")
    assert (hb.autopilot, hb.custom_mode) == (M.MAV_AUTOPILOT_PX4, 1 << 16)
    mav.mav.param_request_read_send(1, 1, b"FW_AIRSPD_TRIM", -1)
    assert mav.need("PARAM_VALUE").param_value == 20.0
    mav.mav.mission_request_list_send(1, 1, M.MAV_MISSION_TYPE_MISSION)
    assert mav.need("MISSION_COUNT").count == 0
    assert mav.command(M.MAV_CMD_GUIDED_CHANGE_HEADING, 1, 90) == M.MAV_RESULT_UNSUPPORTED
    assert mav.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == 0
    assert mav.command(M.MAV_CMD_DO_SET_MODE, 1, 6) == M.MAV_RESULT_TEMPORARILY_REJECTED
    lat, lon, _ = mav.position()
    tlat, tlon = offset(lat, lon, 500.0, 200.0)
    _stream(mav, tlat, tlon, 1.5)
    mav.mav.command_long_send(1, 1, M.MAV_CMD_DO_SET_MODE, 0, 1, 6, 0, 0, 0, 0, 0)
    _stream(mav, tlat, tlon, 0.3)
    assert mav.need("COMMAND_ACK", lambda m: m.command == M.MAV_CMD_DO_SET_MODE).result == 0
    mav.need("HEARTBEAT", lambda m: m.custom_mode == OFFBOARD)
    end = time.monotonic() + 40
    while True:
        _stream(mav, tlat, tlon, 0.5)
        g = mav.need("GLOBAL_POSITION_INT")
        if distance_m(g.lat * 1e-7, g.lon * 1e-7, tlat, tlon) < ARRIVED_M:
            break
        assert time.monotonic() < end, "offboard position setpoint not reached"
    # the stream stops: after COM_OF_LOSS_T the vehicle holds
    assert "Offboard" in mav.need("STATUSTEXT", lambda s: "lost" in s.text).text
    mav.need("HEARTBEAT", lambda m: m.custom_mode == HOLD)
    # DO_REPOSITION in Hold flies to the new point
    blat, blon = offset(tlat, tlon, -300.0, 300.0)
    assert mav.command_int(M.MAV_CMD_DO_REPOSITION, 0, -1, 0, 0, 0, blat, blon, 684) == 0
    mav.need("GLOBAL_POSITION_INT", lambda g: distance_m(g.lat * 1e-7, g.lon * 1e-7, blat, blon) < ARRIVED_M,
             timeout=60)
    other = Mav(ports[1], 2)
    assert other.command(M.MAV_CMD_DO_REPOSITION, -1, 0, 0, 0, blat, blon, 100) == M.MAV_RESULT_FAILED
    assert other.command(M.MAV_CMD_DO_REPOSITION, -1, 1, 0, 0, blat, blon, 100) == 0
    other.need("HEARTBEAT", lambda m: m.custom_mode == HOLD)
    rc, _ = sim.stop()
    assert rc == 0
    mav.close()
    other.close()
