"""Telemetry: which messages stream at what rate (simulated time), and how each is built."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.contracts.frames import LocalFrame, heading_to_yaw
from sim_vehicles.modes import Behaviour
from sim_vehicles.vehicle import Vehicle

M = mavlink
DEFAULT_RATES_HZ = {
    M.MAVLINK_MSG_ID_SYS_STATUS: 1.0,
    M.MAVLINK_MSG_ID_GPS_RAW_INT: 2.0,
    M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 4.0,
    M.MAVLINK_MSG_ID_ATTITUDE: 4.0,
    M.MAVLINK_MSG_ID_VFR_HUD: 2.0,
    M.MAVLINK_MSG_ID_SYSTEM_TIME: 1.0,
    M.MAVLINK_MSG_ID_MISSION_CURRENT: 1.0,
    M.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 0.0,
    M.MAVLINK_MSG_ID_HOME_POSITION: 0.0,
    M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: 0.0,
}
DATA_STREAMS = {  # REQUEST_DATA_STREAM groups, as ArduPilot maps them
    M.MAV_DATA_STREAM_EXTENDED_STATUS: (
        M.MAVLINK_MSG_ID_SYS_STATUS,
        M.MAVLINK_MSG_ID_GPS_RAW_INT,
        M.MAVLINK_MSG_ID_MISSION_CURRENT,
    ),
    M.MAV_DATA_STREAM_POSITION: (M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, M.MAVLINK_MSG_ID_LOCAL_POSITION_NED),
    M.MAV_DATA_STREAM_EXTRA1: (M.MAVLINK_MSG_ID_ATTITUDE,),
    M.MAV_DATA_STREAM_EXTRA2: (M.MAVLINK_MSG_ID_VFR_HUD,),
    M.MAV_DATA_STREAM_EXTRA3: (M.MAVLINK_MSG_ID_SYSTEM_TIME,),
}
DATA_STREAMS[M.MAV_DATA_STREAM_ALL] = tuple(m for ids in DATA_STREAMS.values() for m in ids)
MAX_RATE_HZ = 50.0
SENSORS = (
    M.MAV_SYS_STATUS_SENSOR_3D_GYRO
    | M.MAV_SYS_STATUS_SENSOR_3D_ACCEL
    | M.MAV_SYS_STATUS_SENSOR_3D_MAG
    | M.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
    | M.MAV_SYS_STATUS_SENSOR_GPS
    | M.MAV_SYS_STATUS_AHRS
    | M.MAV_SYS_STATUS_PREARM_CHECK
)
CAPABILITIES = (
    M.MAV_PROTOCOL_CAPABILITY_MISSION_FLOAT
    | M.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
    | M.MAV_PROTOCOL_CAPABILITY_MISSION_INT
    | M.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
    | M.MAV_PROTOCOL_CAPABILITY_SET_ATTITUDE_TARGET
    | M.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_GLOBAL_INT
    | M.MAV_PROTOCOL_CAPABILITY_MAVLINK2
)
SW_VERSION = {"ardupilot": (4, 6, 0), "px4": (1, 15, 0)}


class Streams:
    """Per-vehicle message intervals in simulated seconds (0: off) and when each is next due."""

    def __init__(self) -> None:
        self.interval = {m: (1.0 / r if r > 0 else 0.0) for m, r in DEFAULT_RATES_HZ.items()}
        self.next_due = dict.fromkeys(self.interval, 0.0)
        self.next_any = 0.0

    def set_interval(self, msgid: int, interval_us: float) -> bool:
        """SET_MESSAGE_INTERVAL semantics: -1 off, 0 default, else microseconds. False if unknown."""
        if msgid not in self.interval or not math.isfinite(interval_us):
            return False
        if interval_us < 0:
            self.interval[msgid] = 0.0
        elif interval_us == 0:
            rate = DEFAULT_RATES_HZ[msgid]
            self.interval[msgid] = 1.0 / rate if rate > 0 else 0.0
        else:
            self.interval[msgid] = max(interval_us * 1e-6, 1.0 / MAX_RATE_HZ)
        self.next_any = 0.0
        return True

    def set_stream(self, stream_id: int, rate_hz: int, start: bool) -> bool:
        """REQUEST_DATA_STREAM: every message of the group at `rate_hz` (stop: off)."""
        if stream_id not in DATA_STREAMS:
            return False
        for m in DATA_STREAMS[stream_id]:
            self.set_interval(m, 1e6 / min(rate_hz, MAX_RATE_HZ) if start and rate_hz > 0 else -1)
        return True

    def due(self, t: float) -> list[int]:
        """Messages due at simulated time t (each rescheduled one interval later)."""
        if t < self.next_any:
            return []
        out = []
        for m, iv in self.interval.items():
            if iv > 0 and self.next_due[m] <= t + 1e-9:
                out.append(m)
                self.next_due[m] = max(self.next_due[m] + iv, t)
        self.next_any = min((self.next_due[m] for m, iv in self.interval.items() if iv > 0), default=math.inf)
        return out


@dataclass
class Pose:
    """One vehicle's kinematic state in the local frame, with its geodetic position."""

    x: float
    y: float
    heading: float
    up: float
    vx: float
    vy: float
    vz: float
    omega: float
    roll: float  # bank, positive turning counter-clockwise (MAVLink's roll is the opposite)
    lat: float
    lon: float
    alt: float

    @property
    def groundspeed(self) -> float:
        return math.hypot(self.vx, self.vy)


class TelemetryBuilder:
    """Builds every message a vehicle sends about itself, stamped with simulated time."""

    def __init__(self, frame: LocalFrame, vehicle: Vehicle, unix_epoch_usec: int) -> None:
        self.frame, self.vehicle, self.epoch = frame, vehicle, unix_epoch_usec
        hx, hy = vehicle.home
        self.home = frame.to_geodetic(hx, hy, 0.0)
        self.errors = (0, 0, 0)  # bad frames, unhandled messages, rejected values
        self.builders: dict[int, Callable[[float, Pose], mavlink.MAVLink_message]] = {
            M.MAVLINK_MSG_ID_HEARTBEAT: self.heartbeat,
            M.MAVLINK_MSG_ID_SYS_STATUS: self.sys_status,
            M.MAVLINK_MSG_ID_GPS_RAW_INT: self.gps_raw_int,
            M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: self.global_position_int,
            M.MAVLINK_MSG_ID_LOCAL_POSITION_NED: self.local_position_ned,
            M.MAVLINK_MSG_ID_ATTITUDE: self.attitude,
            M.MAVLINK_MSG_ID_VFR_HUD: self.vfr_hud,
            M.MAVLINK_MSG_ID_SYSTEM_TIME: self.system_time,
            M.MAVLINK_MSG_ID_MISSION_CURRENT: self.mission_current,
            M.MAVLINK_MSG_ID_HOME_POSITION: self.home_position,
            M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: self.extended_sys_state,
            M.MAVLINK_MSG_ID_AUTOPILOT_VERSION: self.autopilot_version,
        }

    def build(self, msgid: int, t: float, pose: Pose) -> mavlink.MAVLink_message:
        return self.builders[msgid](t, pose)

    def heartbeat(self, t: float, pose: Pose) -> mavlink.MAVLink_message:
        v = self.vehicle
        base = M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | M.MAV_MODE_FLAG_STABILIZE_ENABLED
        if v.mode.behaviour not in (Behaviour.STRAIGHT,):
            base |= M.MAV_MODE_FLAG_GUIDED_ENABLED | M.MAV_MODE_FLAG_AUTO_ENABLED
        if v.armed:
            base |= M.MAV_MODE_FLAG_SAFETY_ARMED
        state = M.MAV_STATE_ACTIVE if v.armed else M.MAV_STATE_STANDBY
        return M.MAVLink_heartbeat_message(
            M.MAV_TYPE_FIXED_WING, v.flavour.autopilot, base, v.mode.custom_mode, state, 3
        )

    def sys_status(self, t: float, pose: Pose) -> mavlink.MAVLink_message:
        bad, unhandled, rejected = (min(e, 65535) for e in self.errors)
        v, fence = self.vehicle, M.MAV_SYS_STATUS_GEOFENCE
        present = SENSORS | (fence if v.fence.zones else 0)
        enabled = SENSORS | (fence if v.fence_enabled else 0)
        healthy = SENSORS | (0 if v.fence_breached else fence)
        return M.MAVLink_sys_status_message(
            present, enabled, healthy, 100, 12600, 500, 100, 0, bad, unhandled, rejected, 0, 0
        )

    def gps_raw_int(self, t: float, pose: Pose) -> mavlink.MAVLink_message:
        cog = round(math.degrees(heading_to_yaw(math.atan2(pose.vy, pose.vx))) * 100) % 36000
        return M.MAVLink_gps_raw_int_message(
            int(t * 1e6),
            M.GPS_FIX_TYPE_3D_FIX,
            round(pose.lat * 1e7),
            round(pose.lon * 1e7),
            round(pose.alt * 1000),
            80,
            120,
            round(pose.groundspeed * 100),
            cog,
            12,
        )

    def global_position_int(self, t: float, pose: Pose) -> mavlink.MAVLink_message:
        hdg = round(math.degrees(heading_to_yaw(pose.heading)) * 100) % 36000
        return M.MAVLink_global_position_int_message(
            _ms(t),
            round(pose.lat * 1e7),
            round(pose.lon * 1e7),
            round(pose.alt * 1000),
            round(pose.up * 1000),
            round(pose.vy * 100),
            round(pose.vx * 100),
            round(-pose.vz * 100),
            hdg,
        )

    def local_position_ned(self, t: float, pose: Pose) -> mavlink.MAVLink_message:
        return M.MAVLink_local_position_ned_message(
            _ms(t), pose.y, pose.x, -pose.up, pose.vy, pose.vx, -pose.vz
        )

    def attitude(self, t: float, pose: Pose) -> mavlink.MAVLink_message:
        yaw_rate = -pose.omega  # CW positive, as MAVLink's yaw
        yaw = heading_to_yaw(pose.heading)
        return M.MAVLink_attitude_message(_ms(t), -pose.roll, 0.0, yaw, 0.0, 0.0, yaw_rate)

    def vfr_hud(self, t: float, pose: Pose) -> mavlink.MAVLink_message:
        hdg = round(math.degrees(heading_to_yaw(pose.heading))) % 360
        throttle = 50 if self.vehicle.armed else 0
        return M.MAVLink_vfr_hud_message(pose.groundspeed, pose.groundspeed, hdg, throttle, pose.alt, pose.vz)

    def system_time(self, t: float, pose: Pose) -> mavlink.MAVLink_message:
        return M.MAVLink_system_time_message(self.epoch + int(t * 1e6), _ms(t))

    def mission_current(self, t: float, pose: Pose) -> mavlink.MAVLink_message:
        v = self.vehicle
        return M.MAVLink_mission_current_message(v.current_seq, len(v.mission))

    def home_position(self, t: float, pose: Pose) -> mavlink.MAVLink_message:
        lat, lon, alt = self.home
        hx, hy = self.vehicle.home
        return M.MAVLink_home_position_message(
            round(lat * 1e7),
            round(lon * 1e7),
            round(alt * 1000),
            hy,
            hx,
            0.0,
            [1.0, 0.0, 0.0, 0.0],
            0.0,
            0.0,
            0.0,
            int(t * 1e6),
        )

    def extended_sys_state(self, t: float, pose: Pose) -> mavlink.MAVLink_message:
        return M.MAVLink_extended_sys_state_message(M.MAV_VTOL_STATE_UNDEFINED, M.MAV_LANDED_STATE_IN_AIR)

    def autopilot_version(self, t: float, pose: Pose) -> mavlink.MAVLink_message:
        major, minor, patch = SW_VERSION[self.vehicle.flavour.name]
        version = (major << 24) | (minor << 16) | (patch << 8) | M.FIRMWARE_VERSION_TYPE_OFFICIAL
        sysid = self.vehicle.sysid
        return M.MAVLink_autopilot_version_message(
            CAPABILITIES, version, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0, 0x53494D00 + sysid
        )


def _ms(t: float) -> int:
    """time_boot_ms of simulated time t (wraps after 49 days, as the uint32 field does)."""
    return round(t * 1000) % (1 << 32)
