"""pymavlink against the ArduPilot flavour: identity, commands, parameters, missions, guidance,
failsafe, MAVFTP NAK and bad input. One simulator (10x speedup, continuous kinematics), one
vehicle per test so the tests do not disturb each other."""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator

import pytest

from tests.sim.conftest import ARRIVED_M, M, Mav, SimProcess, distance_m, offset, write_mission

N = 8


@pytest.fixture(scope="module")
def sim(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[SimProcess, list[int]]]:
    path, ports, _ = write_mission(tmp_path_factory.mktemp("ardu"), n=N)
    proc = SimProcess(path, "--speedup", "10", "--no-camera")
    try:
        proc.wait_ready(N)
        yield proc, ports
        rc, stats = proc.stop()
        assert rc == 0 and stats["sim_time"] > 0
    finally:
        proc.kill()


@pytest.fixture
def mav(sim: tuple[SimProcess, list[int]], request: pytest.FixtureRequest) -> Iterator[Mav]:
    index = request.param
    client = Mav(sim[1][index], sysid=index + 1)
    yield client
    client.close()


def _guided_armed(mav: Mav) -> None:
    assert mav.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_ACCEPTED
    assert mav.command(M.MAV_CMD_DO_SET_MODE, 1, 15) == M.MAV_RESULT_ACCEPTED


@pytest.mark.parametrize("mav", [0], indirect=True)
def test_identity_streams_and_requests(mav: Mav) -> None:
    hb = mav.need("HEARTBEAT")
    assert (hb.type, hb.autopilot, hb.custom_mode) == (
        M.MAV_TYPE_FIXED_WING,
        M.MAV_AUTOPILOT_ARDUPILOTMEGA,
        0,
    )
    assert not hb.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED
    status = mav.need("SYS_STATUS")
    for field in ("onboard_control_sensors_present", "onboard_control_sensors_health"):
        bits = getattr(status, field)
        assert bits & M.MAV_SYS_STATUS_PREARM_CHECK and bits & M.MAV_SYS_STATUS_SENSOR_GPS
    assert mav.need("GPS_RAW_INT").fix_type == M.GPS_FIX_TYPE_3D_FIX
    mav.need("ATTITUDE")
    mav.need("VFR_HUD")
    mav.need("SYSTEM_TIME")
    assert mav.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION) == 0
    caps = mav.need("AUTOPILOT_VERSION").capabilities
    for cap in ("MISSION_INT", "COMMAND_INT", "SET_POSITION_TARGET_GLOBAL_INT", "MAVLINK2"):
        assert caps & getattr(M, f"MAV_PROTOCOL_CAPABILITY_{cap}")
    assert mav.command(M.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES, 1) == 0
    mav.need("AUTOPILOT_VERSION")
    assert mav.command(M.MAV_CMD_GET_HOME_POSITION) == 0
    home = mav.need("HOME_POSITION")
    assert abs(home.altitude / 1000 - 584.0) < 0.01
    assert mav.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_HOME_POSITION) == 0
    mav.need("HOME_POSITION")
    assert mav.command(M.MAV_CMD_REQUEST_MESSAGE, 9999) == M.MAV_RESULT_UNSUPPORTED
    assert mav.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_LOCAL_POSITION_NED, 100000) == 0
    mav.need("LOCAL_POSITION_NED")
    assert mav.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, 9999, 100000) == M.MAV_RESULT_UNSUPPORTED
    mav.mav.request_data_stream_send(mav.sysid, 1, M.MAV_DATA_STREAM_ALL, 4, 1)
    mav.need("GLOBAL_POSITION_INT")
    assert mav.command(12345) == M.MAV_RESULT_UNSUPPORTED
    assert mav.command(31010, 1) == M.MAV_RESULT_UNSUPPORTED  # lockstep is off


@pytest.mark.parametrize("mav", [1], indirect=True)
def test_arm_and_modes(mav: Mav, sim: tuple[SimProcess, list[int]]) -> None:
    assert mav.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 5) == M.MAV_RESULT_DENIED
    assert mav.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_ACCEPTED
    mav.need("HEARTBEAT", lambda m: m.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED)
    assert mav.command(M.MAV_CMD_DO_SET_MODE, 1, 15) == M.MAV_RESULT_ACCEPTED
    mav.need("HEARTBEAT", lambda m: m.custom_mode == 15)
    mav.mav.set_mode_send(mav.sysid, 1, 12)
    assert mav.need("COMMAND_ACK", lambda m: m.command == M.MAVLINK_MSG_ID_SET_MODE).result == 0
    mav.need("HEARTBEAT", lambda m: m.custom_mode == 12)
    assert mav.command(M.MAV_CMD_DO_SET_MODE, 1, 99) == M.MAV_RESULT_FAILED
    assert mav.command(M.MAV_CMD_DO_SET_MODE, 1, 10) == M.MAV_RESULT_FAILED  # AUTO, no mission
    # a second client on the same vehicle gets the telemetry too
    other = Mav(sim[1][1], sysid=2, source_system=251)
    other.need("GLOBAL_POSITION_INT")
    other.close()
    assert mav.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 0) == M.MAV_RESULT_ACCEPTED
    mav.need("HEARTBEAT", lambda m: not m.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED)


@pytest.mark.parametrize("mav", [2], indirect=True)
def test_parameters_change_behaviour(mav: Mav) -> None:
    mav.mav.param_request_list_send(mav.sysid, 1)
    first = mav.need("PARAM_VALUE")
    names = {first.param_id} | {mav.need("PARAM_VALUE").param_id for _ in range(first.param_count - 1)}
    assert names == {
        "AIRSPEED_CRUISE",
        "AIRSPEED_MIN",
        "AIRSPEED_MAX",
        "SIM_TURN_LIMIT",
        "ROLL_LIMIT_DEG",
        "SIM_GUIDED_TMO",
        "WP_RADIUS",
        "WP_LOITER_RAD",
        "FENCE_ENABLE",
        "FENCE_ACTION",
        "FENCE_TYPE",
        "FS_GCS_ENABL",
        "MAV_GCS_SYSID",
        "FS_SHORT_ACTN",
        "FS_SHORT_TIMEOUT",
        "FS_LONG_ACTN",
        "FS_LONG_TIMEOUT",
        "RTL_ALTITUDE",
    }
    mav.mav.param_request_read_send(mav.sysid, 1, b"WP_RADIUS", -1)
    assert mav.need("PARAM_VALUE", lambda m: m.param_id == "WP_RADIUS").param_value == 40.0
    mav.mav.param_request_read_send(mav.sysid, 1, b"", 0)
    assert mav.need("PARAM_VALUE").param_id == "AIRSPEED_CRUISE"
    mav.mav.param_set_send(mav.sysid, 1, b"AIRSPEED_CRUISE", 26.0, M.MAV_PARAM_TYPE_REAL32)
    assert mav.need("PARAM_VALUE", lambda m: m.param_id == "AIRSPEED_CRUISE").param_value == 26.0
    mav.mav.param_set_send(mav.sysid, 1, b"AIRSPEED_CRUISE", 1e9, M.MAV_PARAM_TYPE_REAL32)
    assert mav.need("PARAM_VALUE", lambda m: m.param_id == "AIRSPEED_CRUISE").param_value == 26.0
    assert mav.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == 0
    assert abs(mav.need("VFR_HUD", lambda m: m.groundspeed > 1).groundspeed - 26.0) < 0.01
    assert mav.command(M.MAV_CMD_DO_CHANGE_SPEED, 0, 15) == 0
    mav.need("VFR_HUD", lambda m: abs(m.groundspeed - 15.0) < 0.01)
    assert mav.command(M.MAV_CMD_DO_CHANGE_SPEED, 0, 1e6) == M.MAV_RESULT_DENIED


@pytest.mark.parametrize("mav", [3], indirect=True)
def test_reposition_flies_there_and_loiters(mav: Mav) -> None:
    lat, lon, _ = mav.position()
    tlat, tlon = offset(lat, lon, 600.0, 300.0)
    assert mav.command_int(M.MAV_CMD_DO_REPOSITION, 3, -1, 0, 0, 0, tlat, tlon, 100) == M.MAV_RESULT_FAILED
    assert mav.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == 0
    assert mav.command_int(M.MAV_CMD_DO_REPOSITION, 3, -1, 95.0, 0, 0, 95.0, tlon, 100) == M.MAV_RESULT_DENIED
    assert mav.command_int(M.MAV_CMD_DO_REPOSITION, 3, -1, 1, 0, 0, tlat, tlon, 120) == 0
    mav.need("HEARTBEAT", lambda m: m.custom_mode == 15)
    mav.need(
        "GLOBAL_POSITION_INT",
        lambda g: distance_m(g.lat * 1e-7, g.lon * 1e-7, tlat, tlon) < ARRIVED_M,
        timeout=60,
    )
    t0 = mav.sim_time()
    while mav.sim_time() < t0 + 40:  # then it loiters around the point
        g = mav.need("GLOBAL_POSITION_INT")
        assert distance_m(g.lat * 1e-7, g.lon * 1e-7, tlat, tlon) < 200
    assert abs(g.relative_alt / 1000 - 120) < 1
    # COMMAND_LONG form, in GUIDED already (no change-mode flag needed)
    blat, blon = offset(tlat, tlon, -400.0, 0.0)
    mav.mav.command_long_send(mav.sysid, 1, M.MAV_CMD_DO_REPOSITION, 0, -1, 0, 0, 0, blat, blon, 100)
    assert mav.need("COMMAND_ACK", lambda m: m.command == M.MAV_CMD_DO_REPOSITION).result == 0
    mav.need(
        "GLOBAL_POSITION_INT",
        lambda g: distance_m(g.lat * 1e-7, g.lon * 1e-7, blat, blon) < ARRIVED_M,
        timeout=60,
    )
    assert mav.command(M.MAV_CMD_NAV_RETURN_TO_LAUNCH) == 0
    mav.need("HEARTBEAT", lambda m: m.custom_mode == 11)


@pytest.mark.parametrize("mav", [4], indirect=True)
def test_heading_hold_param3_and_altitude(mav: Mav) -> None:
    """GUIDED_CHANGE_HEADING as ArduPlane flies it: param3 is the largest centripetal acceleration
    (0 means it does not turn), the hold does not expire; altitude from GUIDED_CHANGE_ALTITUDE
    and from SET_POSITION_TARGET_GLOBAL_INT (its lat/lon ignored)."""
    assert mav.command(M.MAV_CMD_GUIDED_CHANGE_HEADING, 1, 270, 5) == M.MAV_RESULT_FAILED  # not GUIDED
    _guided_armed(mav)
    assert mav.command(M.MAV_CMD_GUIDED_CHANGE_HEADING, 1, 400, 5) == M.MAV_RESULT_DENIED
    yaw0 = math.degrees(mav.need("ATTITUDE").yaw)
    assert mav.command(M.MAV_CMD_GUIDED_CHANGE_HEADING, 1, 270, 0) == 0  # clamped to 0.05 m/s^2
    t0 = mav.sim_time()
    while mav.sim_time() < t0 + 10:
        assert abs(math.degrees(mav.need("ATTITUDE").yaw) - yaw0) < 5, "turned with param3 = 0"
    assert mav.command(M.MAV_CMD_GUIDED_CHANGE_HEADING, 1, 270, 5) == 0
    limit = math.degrees(math.atan(5 / 9.80665))  # 27 degrees of bank
    rolls = []
    while abs(math.degrees((a := mav.need("ATTITUDE")).yaw) + 90) > 2:
        rolls.append(abs(math.degrees(a.roll)))
        assert len(rolls) < 400, "no heading of 270 within 100 s"
    assert limit - 2 < max(rolls) <= limit + 0.1
    t_hold = mav.sim_time()
    while mav.sim_time() < t_hold + 10:  # no guidance timeout for a heading (SIM_GUIDED_TMO is 3 s)
        assert abs(math.degrees(mav.need("ATTITUDE").yaw) + 90) < 2
    mav.need("HEARTBEAT", lambda m: m.custom_mode == 15)
    assert mav.command_int(M.MAV_CMD_GUIDED_CHANGE_ALTITUDE, 3, 0, 0, 0, 0, 0, 0, 125) == 0
    mav.need("GLOBAL_POSITION_INT", lambda g: abs(g.relative_alt / 1000 - 125) < 0.5, timeout=30)
    lat, lon, _ = mav.position()
    flat, flon = offset(lat, lon, 5000.0, 5000.0)
    mav.mav.set_position_target_global_int_send(
        0,
        mav.sysid,
        1,
        M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
        0b110111111000,
        round(flat * 1e7),
        round(flon * 1e7),
        130,
        0,
        0,
        0,
        0,
        0,
        0,
        0,
        0,
    )
    mav.need("GLOBAL_POSITION_INT", lambda g: abs(g.relative_alt / 1000 - 130) < 0.5, timeout=30)
    assert abs(math.degrees(mav.need("ATTITUDE").yaw) + 90) < 2
    assert mav.command(M.MAV_CMD_GUIDED_CHANGE_SPEED, 0, 18) == 0


@pytest.mark.parametrize("mav", [7], indirect=True)
def test_turn_rate_bank_limit_and_guidance_timeout(mav: Mav) -> None:
    """The simulator's turn-rate command (SET_ATTITUDE_TARGET body yaw rate, clockwise positive):
    flown once the roll has settled, limited by the bank limit; SIM_GUIDED_TMO after the last one
    the vehicle goes back to circling its guided point, still in GUIDED (as ArduPlane does when a
    SET_ATTITUDE_TARGET expires)."""
    _guided_armed(mav)
    rate = 0.15

    def turning(expected: float) -> Callable[[object], bool]:
        def check(a: object) -> bool:
            mav.mav.set_attitude_target_send(0, mav.sysid, 1, 195, [1, 0, 0, 0], 0, 0, rate_sent, 0)
            return abs(a.yawspeed - expected) < 1e-3

        return check

    rate_sent = rate
    mav.need("ATTITUDE", turning(rate), timeout=30)
    rate_sent = 1.0  # more than a 45 degree bank gives at 20 m/s
    bank_limited = 0.7 * 9.80665 * math.tan(math.radians(45)) / 20.0  # TURN_EFFICIENCY g tan(45) / v
    att = mav.need("ATTITUDE", turning(bank_limited), timeout=30)
    assert abs(math.degrees(att.roll) - 45) < 0.1
    rate_sent = rate
    mav.need("ATTITUDE", turning(rate), timeout=30)
    t_last = mav.sim_time()  # the last command was sent just before this
    att = mav.need("ATTITUDE", lambda a: abs(a.yawspeed - rate) > 0.02, timeout=30)
    assert mav.sim_time() >= t_last + 3.0
    assert mav.need("HEARTBEAT").custom_mode == 15


@pytest.mark.parametrize("mav", [5], indirect=True)
def test_mission_upload_download_fly(mav: Mav) -> None:
    mav.mav.mission_request_list_send(mav.sysid, 1, M.MAV_MISSION_TYPE_MISSION)
    assert mav.need("MISSION_COUNT").count == 1  # ArduPilot: home only
    for mission_type in (M.MAV_MISSION_TYPE_FENCE, M.MAV_MISSION_TYPE_RALLY):
        mav.mav.mission_request_list_send(mav.sysid, 1, mission_type)
        reply = mav.need("MISSION_COUNT", lambda m, t=mission_type: m.mission_type == t)
        assert reply.count == 0
    mav.mav.mission_count_send(mav.sysid, 1, 1, M.MAV_MISSION_TYPE_RALLY)
    assert mav.need("MISSION_ACK").type == M.MAV_MISSION_UNSUPPORTED
    lat, lon, _ = mav.position()
    points = [(lat, lon), offset(lat, lon, 500.0, 0.0), offset(lat, lon, 500.0, 500.0)]
    mav.mav.mission_count_send(mav.sysid, 1, len(points), M.MAV_MISSION_TYPE_MISSION)
    for _ in points:
        req = mav.need("MISSION_REQUEST_INT")
        plat, plon = points[req.seq]
        mav.mav.mission_item_int_send(
            mav.sysid,
            1,
            req.seq,
            M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
            M.MAV_CMD_NAV_WAYPOINT,
            0,
            1,
            0,
            0,
            0,
            0,
            round(plat * 1e7),
            round(plon * 1e7),
            100,
        )
    assert mav.need("MISSION_ACK").type == M.MAV_MISSION_ACCEPTED
    mav.mav.mission_request_list_send(mav.sysid, 1, M.MAV_MISSION_TYPE_MISSION)
    assert mav.need("MISSION_COUNT").count == 3
    mav.mav.mission_request_int_send(mav.sysid, 1, 2, M.MAV_MISSION_TYPE_MISSION)
    item = mav.need("MISSION_ITEM_INT")
    assert (item.seq, item.x, item.y) == (2, round(points[2][0] * 1e7), round(points[2][1] * 1e7))
    mav.mav.mission_request_int_send(mav.sysid, 1, 7, M.MAV_MISSION_TYPE_MISSION)
    assert mav.need("MISSION_ACK").type == M.MAV_MISSION_INVALID_SEQUENCE
    assert mav.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == 0
    assert mav.command(M.MAV_CMD_DO_SET_MODE, 1, 10) == 0
    assert mav.need("MISSION_ITEM_REACHED", timeout=60).seq == 1
    assert mav.need("MISSION_ITEM_REACHED", timeout=60).seq == 2
    mav.need("HEARTBEAT", lambda m: m.custom_mode == 11, timeout=30)  # mission end: RTL
    mav.mav.mission_clear_all_send(mav.sysid, 1, M.MAV_MISSION_TYPE_MISSION)
    assert mav.need("MISSION_ACK").type == M.MAV_MISSION_ACCEPTED
    mav.mav.mission_request_list_send(mav.sysid, 1, M.MAV_MISSION_TYPE_MISSION)
    assert mav.need("MISSION_COUNT").count == 1


@pytest.mark.parametrize("mav", [6], indirect=True)
def test_ftp_nak_and_bad_input(mav: Mav) -> None:
    request = bytes([0, 0, 0, 4, 1, 0, 0, 0, 0, 0, 0, 0, ord("/")]) + bytes(238)
    mav.mav.file_transfer_protocol_send(0, mav.sysid, 1, list(request))
    nak = mav.need("FILE_TRANSFER_PROTOCOL")
    assert nak.payload[3] == 129 and nak.payload[5] == 4 and nak.payload[12] == 10
    sock_write = mav.conn.write
    sock_write(b"\x00garbage that is not mavlink\xff" * 3)
    sock_write(b"\xfd\x09\x00\x00\x00\xff\x01")  # truncated
    good = mav.mav.command_long_encode(mav.sysid, 1, M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
    frame = bytearray(good.pack(mav.mav))
    frame[-1] ^= 0xFF  # bad CRC
    sock_write(bytes(frame))
    sock_write(bytes(range(256)) * 4)
    mav.mav.command_long_send(mav.sysid, 1, M.MAV_CMD_DO_CHANGE_SPEED, 0, 0, math.nan, 0, 0, 0, 0, 0)
    assert mav.need("COMMAND_ACK").result == M.MAV_RESULT_DENIED
    mav.mav.param_set_send(mav.sysid, 1, b"NO_SUCH_PARAM", 1.0, M.MAV_PARAM_TYPE_REAL32)
    mav.mav.set_attitude_target_send(0, mav.sysid, 1, 195, [1, 0, 0, 0], 0, 0, math.inf, 0)
    assert mav.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == 0  # still answering
    status = mav.need("SYS_STATUS", lambda s: s.errors_comm >= 4 and s.errors_count2 >= 3)
    assert status.errors_comm >= 4
    assert "Bad input" in mav.need("STATUSTEXT", lambda s: "Bad input" in s.text).text
