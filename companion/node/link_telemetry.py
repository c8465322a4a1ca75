"""The vehicle link's telemetry: the latest vehicle state, in the mission's local frame."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.contracts.frames import LocalFrame, yaw_to_heading

COURSE_MIN_SPEED = 3.0  # m/s: slower than this the heading is ATTITUDE's yaw (PX4)
STREAMS_HZ = {
    mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 10.0,
    mavlink.MAVLINK_MSG_ID_ATTITUDE: 10.0,
    mavlink.MAVLINK_MSG_ID_SYS_STATUS: 1.0,
    mavlink.MAVLINK_MSG_ID_SYSTEM_TIME: 1.0,
    mavlink.MAVLINK_MSG_ID_GPS_RAW_INT: 1.0,
}


@dataclass
class VehicleState:
    """The latest telemetry, in the mission's local frame (x east, y north, heading CCW from east)."""

    system: int = 0
    autopilot: int = 0
    custom_mode: int = -1
    armed: bool = False
    time_s: float = -1.0  # vehicle time of the latest position
    x: float = math.nan
    y: float = math.nan
    up: float = math.nan
    home_amsl: float = math.nan  # the altitude of home (m AMSL), from GLOBAL_POSITION_INT
    heading: float = math.nan
    turn_rate: float = 0.0  # heading rate (rad/s, CCW positive) from ATTITUDE
    moving: bool = False  # PX4: fast enough for the heading to be the course over ground
    last_heartbeat: float = -math.inf  # wall clock (time.monotonic) of the latest HEARTBEAT
    gps_fix: int = 0  # GPS_RAW_INT.fix_type (3: 3D)
    prearm_ok: bool = False  # SYS_STATUS: pre-arm checks present and passing
    texts: list[str] = field(default_factory=list)  # the latest STATUSTEXTs
    text_count: int = 0  # STATUSTEXTs received so far

    @property
    def px4(self) -> bool:
        return self.autopilot == mavlink.MAV_AUTOPILOT_PX4

    def texts_since(self, count: int) -> list[str]:
        """The STATUSTEXTs kept that came after the first `count`."""
        return self.texts[max(len(self.texts) - (self.text_count - count), 0) :]

    @property
    def has_pose(self) -> bool:
        return self.time_s >= 0 and math.isfinite(self.x) and math.isfinite(self.heading)

    def update(self, msg: mavlink.MAVLink_message, frame: LocalFrame) -> bool:
        """Take in one of the autopilot's telemetry messages; False for a message of another kind.

        On PX4 the heading is the course over ground while the vehicle moves (its fixed-wing flies
        with sideslip), ATTITUDE's yaw otherwise.
        """
        kind = msg.get_type()
        if kind == "HEARTBEAT":
            if msg.get_srcComponent() != mavlink.MAV_COMP_ID_AUTOPILOT1 or msg.type == mavlink.MAV_TYPE_GCS:
                return True
            self.system, self.autopilot = msg.get_srcSystem(), msg.autopilot
            self.custom_mode = msg.custom_mode
            self.armed = bool(msg.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
            self.last_heartbeat = time.monotonic()
        elif kind == "GLOBAL_POSITION_INT":
            self._position(msg, frame)
        elif kind == "ATTITUDE":
            if not self.moving:
                self.heading = yaw_to_heading(msg.yaw)
            # body yaw rate = heading rate * cos(roll) * cos(pitch) in a level turn; CW positive
            self.turn_rate = -msg.yawspeed / max(math.cos(msg.roll) * math.cos(msg.pitch), 0.2)
        elif kind == "GPS_RAW_INT":
            self.gps_fix = msg.fix_type
        elif kind == "SYS_STATUS":
            bit = mavlink.MAV_SYS_STATUS_PREARM_CHECK
            self.prearm_ok = bool(
                msg.onboard_control_sensors_present & msg.onboard_control_sensors_health & bit
            )
        elif kind == "STATUSTEXT":
            self.texts.append(msg.text)
            self.text_count += 1
            del self.texts[:-50]
        else:
            return False
        return True

    def _position(self, msg: mavlink.MAVLink_message, frame: LocalFrame) -> None:
        """GLOBAL_POSITION_INT: position, height above home, home's altitude, PX4's course."""
        self.x, self.y = frame.to_local(msg.lat * 1e-7, msg.lon * 1e-7)
        self.up = msg.relative_alt * 1e-3
        self.home_amsl = (msg.alt - msg.relative_alt) * 1e-3
        self.moving = self.px4 and math.hypot(msg.vx, msg.vy) * 0.01 >= COURSE_MIN_SPEED
        if self.moving:  # vx north, vy east (cm/s)
            self.heading = math.atan2(msg.vx, msg.vy)
        elif not math.isfinite(self.heading) and msg.hdg != 65535:
            self.heading = yaw_to_heading(math.radians(msg.hdg * 0.01))
        self.time_s = msg.time_boot_ms * 1e-3
