"""Autopilot flavours: heartbeat identity, custom flight modes and what each mode flies."""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

from pymavlink.dialects.v20 import ardupilotmega as mavlink


class Behaviour(Enum):
    """What the simulated vehicle does in a mode."""

    STRAIGHT = "straight"  # wings level, no navigation (manual-like modes without RC)
    LOITER = "loiter"  # circle the position where the mode was entered
    AUTO = "auto"  # fly the uploaded mission
    RTL = "rtl"  # fly home and circle it
    GUIDED = "guided"  # ArduPlane GUIDED: external guidance
    OFFBOARD = "offboard"  # PX4 OFFBOARD: external setpoint stream


@dataclass(frozen=True)
class Mode:
    name: str
    custom_mode: int
    behaviour: Behaviour


def _px4(main: int, sub: int = 0) -> int:
    """PX4 custom_mode: main mode in bits 16-23, sub mode in bits 24-31."""
    return (main << 16) | (sub << 24)


@dataclass(frozen=True)
class Flavour:
    """One autopilot's MAVLink identity and mode table."""

    name: str
    autopilot: int
    modes: tuple[Mode, ...]
    initial: str
    hold: str  # where GUIDED/OFFBOARD guidance loss goes
    reposition: str  # the mode MAV_CMD_DO_REPOSITION flies in
    rtl: str
    mission_end: str
    home_is_item0: bool  # ArduPilot keeps home as mission item 0
    nav_period: float  # s: the period and damping of its lateral guidance (dynamics.navigation)
    nav_damping: float

    def by_custom(self, custom_mode: int) -> Mode | None:
        return next((m for m in self.modes if m.custom_mode == custom_mode), None)

    def by_name(self, name: str) -> Mode:
        return next(m for m in self.modes if m.name == name)

    def custom_from_do_set_mode(self, param2: float, param3: float) -> int:
        """The custom_mode a MAV_CMD_DO_SET_MODE asks for (PX4 splits it into main and sub mode)."""
        if self.autopilot == mavlink.MAV_AUTOPILOT_PX4:
            return _px4(int(param2), int(param3))
        return int(param2)


ARDUPLANE = Flavour(
    name="ardupilot",
    autopilot=mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
    modes=(
        Mode("MANUAL", 0, Behaviour.STRAIGHT),
        Mode("CIRCLE", 1, Behaviour.LOITER),
        Mode("STABILIZE", 2, Behaviour.STRAIGHT),
        Mode("FBWA", 5, Behaviour.STRAIGHT),
        Mode("AUTO", 10, Behaviour.AUTO),
        Mode("RTL", 11, Behaviour.RTL),
        Mode("LOITER", 12, Behaviour.LOITER),
        Mode("TAKEOFF", 13, Behaviour.LOITER),
        Mode("GUIDED", 15, Behaviour.GUIDED),
    ),
    initial="MANUAL",
    hold="LOITER",
    reposition="GUIDED",
    rtl="RTL",
    mission_end="RTL",
    home_is_item0=True,
    nav_period=15.0,  # plane.parm's NAVL1_PERIOD, NAVL1_DAMPING
    nav_damping=0.75,
)

PX4 = Flavour(
    name="px4",
    autopilot=mavlink.MAV_AUTOPILOT_PX4,
    modes=(
        Mode("MANUAL", _px4(1), Behaviour.STRAIGHT),
        Mode("ALTCTL", _px4(2), Behaviour.STRAIGHT),
        Mode("POSCTL", _px4(3), Behaviour.STRAIGHT),
        Mode("AUTO.LOITER", _px4(4, 3), Behaviour.LOITER),
        Mode("AUTO.MISSION", _px4(4, 4), Behaviour.AUTO),
        Mode("AUTO.RTL", _px4(4, 5), Behaviour.RTL),
        Mode("OFFBOARD", _px4(6), Behaviour.OFFBOARD),
        Mode("STABILIZED", _px4(7), Behaviour.STRAIGHT),
    ),
    initial="MANUAL",
    hold="AUTO.LOITER",
    reposition="AUTO.LOITER",
    rtl="AUTO.RTL",
    mission_end="AUTO.LOITER",
    home_is_item0=False,
    nav_period=10.0,  # PX4's NPFG_PERIOD, NPFG_DAMPING
    nav_damping=0.7,
)

FLAVOURS = {f.name: f for f in (ARDUPLANE, PX4)}
