"""The vehicle link's commands: mode, arming, take-off and the guidance setpoints."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from pymavlink.dialects.v20 import ardupilotmega as mavlink

if TYPE_CHECKING:
    from companion.node.vehicle_link import VehicleLink


class Commands:
    """What the companion tells the autopilot over one link (`link.commands`).

    PX4 differs where the methods say: it reads DO_REPOSITION's altitude as AMSL whatever the frame
    and answers it UNSUPPORTED without the change-mode flag.
    """

    def __init__(self, link: VehicleLink) -> None:
        self.link = link

    def set_mode(self, custom_mode: int) -> None:
        """MAV_CMD_DO_SET_MODE with a custom mode (PX4: main and sub mode split into params 2 and 3)."""
        flag = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        if self.link.state.px4:
            main, sub = (custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF
            self.link.command_long(mavlink.MAV_CMD_DO_SET_MODE, flag, main, sub)
        else:
            self.link.command_long(mavlink.MAV_CMD_DO_SET_MODE, flag, custom_mode)

    def arm(self) -> None:
        """MAV_CMD_COMPONENT_ARM_DISARM: arm."""
        self.link.command_long(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)

    def takeoff(self, up: float) -> int | None:
        """MAV_CMD_NAV_TAKEOFF to `up` metres above home; the MAV_RESULT, or None.

        PX4 reads AMSL in param7 and switches to AUTO.TAKEOFF.
        """
        z = self.link.state.home_amsl + up
        return self.link.command_ack(mavlink.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, math.nan, math.nan, z)

    def change_speed(self, speed: float) -> None:
        """MAV_CMD_DO_CHANGE_SPEED: airspeed (type 0) in m/s, throttle unchanged."""
        self.link.command_long(mavlink.MAV_CMD_DO_CHANGE_SPEED, 0, speed, -1)

    def turn_rate(self, rate: float) -> None:
        """Body yaw rate (rad/s, MAVLink sign: positive turns clockwise) via SET_ATTITUDE_TARGET."""
        ignore = (
            mavlink.ATTITUDE_TARGET_TYPEMASK_BODY_ROLL_RATE_IGNORE
            | mavlink.ATTITUDE_TARGET_TYPEMASK_BODY_PITCH_RATE_IGNORE
            | mavlink.ATTITUDE_TARGET_TYPEMASK_THROTTLE_IGNORE
            | mavlink.ATTITUDE_TARGET_TYPEMASK_ATTITUDE_IGNORE
        )
        system, autopilot = self.link.state.system, mavlink.MAV_COMP_ID_AUTOPILOT1
        self.link.mav.set_attitude_target_send(
            0, system, autopilot, ignore, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, rate, 0.0
        )

    def change_heading(self, yaw_deg: float, accel: float) -> None:
        """MAV_CMD_GUIDED_CHANGE_HEADING to `yaw_deg`, turning with at most `accel` m/s^2.

        Heading type 1 (heading), 0-360 degrees clockwise from north; param3 is the largest
        centripetal acceleration (m/s^2) the turn may use (ArduPlane: bank limit atan(accel / g); it
        clamps the value to at least 0.05, so 0 means "do not turn").
        """
        self.link.command_long(mavlink.MAV_CMD_GUIDED_CHANGE_HEADING, 1, yaw_deg % 360.0, accel)

    def change_altitude(self, up: float) -> None:
        """MAV_CMD_GUIDED_CHANGE_ALTITUDE to `up` metres above home, at the autopilot's climb rate.

        Sent as COMMAND_INT, relative altitude; param3 0 means the autopilot's own climb rate.
        """
        self.link.command_int(
            mavlink.MAV_CMD_GUIDED_CHANGE_ALTITUDE,
            mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
            (0.0, 0.0, 0.0, 0.0),
            0,
            0,
            up,
        )

    def reposition(self, lat: float, lon: float, up: float) -> None:
        """MAV_CMD_DO_REPOSITION as COMMAND_INT to `up` metres above home.

        ArduPilot: relative altitude, without the change-mode flag (it flies it in GUIDED). PX4:
        AMSL (it reads the altitude as AMSL whatever the frame) with the change-mode flag (without
        it PX4 answers UNSUPPORTED; with it, it switches to Hold).
        """
        s = self.link.state
        if s.px4:
            frame, flags, z = (
                mavlink.MAV_FRAME_GLOBAL_INT,
                mavlink.MAV_DO_REPOSITION_FLAGS_CHANGE_MODE,
                s.home_amsl + up,
            )
        else:
            frame, flags, z = mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, 0, up
        self.link.command_int(
            mavlink.MAV_CMD_DO_REPOSITION,
            frame,
            (-1.0, float(flags), 0.0, math.nan),
            round(lat * 1e7),
            round(lon * 1e7),
            z,
        )

    def position_target(self, lat: float, lon: float, up: float) -> None:
        """SET_POSITION_TARGET_GLOBAL_INT, position only, `up` metres above home as AMSL (PX4 OFFBOARD).

        AMSL: home's altitude as GLOBAL_POSITION_INT gives it (alt - relative_alt) plus `up`, which
        PX4 turns into the local setpoint ref_alt - alt, so that the relative altitude it reports
        settles at `up`. PX4's GLOBAL_RELATIVE_ALT_INT conversion (mavlink_receiver: z = home alt -
        alt - ref_alt) is off by twice home's height in its local frame (a few metres in SIH: one
        aircraft flew 3-5 m above its layer). Relative, as before, until home is known.
        """
        mask = (
            mavlink.POSITION_TARGET_TYPEMASK_VX_IGNORE
            | mavlink.POSITION_TARGET_TYPEMASK_VY_IGNORE
            | mavlink.POSITION_TARGET_TYPEMASK_VZ_IGNORE
            | mavlink.POSITION_TARGET_TYPEMASK_AX_IGNORE
            | mavlink.POSITION_TARGET_TYPEMASK_AY_IGNORE
            | mavlink.POSITION_TARGET_TYPEMASK_AZ_IGNORE
            | mavlink.POSITION_TARGET_TYPEMASK_YAW_IGNORE
            | mavlink.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE
        )
        home = self.link.state.home_amsl
        frame, z = (
            (mavlink.MAV_FRAME_GLOBAL_INT, home + up)
            if math.isfinite(home)
            else (mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, up)
        )
        self.link.mav.set_position_target_global_int_send(
            0,
            self.link.state.system,
            mavlink.MAV_COMP_ID_AUTOPILOT1,
            frame,
            mask,
            round(lat * 1e7),
            round(lon * 1e7),
            z,
            *([0] * 8),
        )
