"""The parameter set (names and defaults per flavour, ranges, read-only rules) and the parameter protocol.

Values travel as REAL32, except the PX4 flavour's integer parameters, which go as INT32 with their
bytes in PARAM_VALUE's float, as PX4 sends them (ArduPilot casts).
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from typing import TYPE_CHECKING

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.contracts.mission import Mission

if TYPE_CHECKING:
    from sim_vehicles.hosted_vehicle import HostedVehicle
    from sim_vehicles.mavlink_endpoint import Address

ROLL_LIMIT_DEG = 45.0  # ArduPlane's default bank limit
# PX4's defaults (checked on PX4 SITL's SIH fixed-wing)
PX4_ROLL_LIMIT_DEG, PX4_LOITER_RADIUS, PX4_ACCEPTANCE_RADIUS, PX4_OFFBOARD_LOSS_S = 50.0, 80.0, 10.0, 1.0
RTL_ALTITUDE_M, PX4_RTL_DESCEND_M = 100.0, 30.0  # ArduPlane's RTL_ALTITUDE, PX4's RTL_DESCEND_ALT
PX4_GEOFENCE_HOLD = 2  # GF_ACTION: 0 none, 1 warning, 2 Hold, 3 Return, 4 terminate, 5 land


@dataclass(frozen=True)
class ParamSpec:
    """One simulator parameter: its key, names, default and accepted range.

    The internal key, its name in each flavour (None: the flavour has none), the default
    (`px4_default`: another one in the PX4 flavour) and the accepted range.
    """

    key: str
    ardupilot: str | None
    px4: str | None
    default: float
    lo: float
    hi: float
    fixed_in_grid: bool = False  # grid kinematics pins it (one cell per step)
    px4_default: float | None = None
    integer: bool = False  # PX4 sends it as INT32


def param_specs(mission: Mission) -> tuple[ParamSpec, ...]:
    """The simulator's parameters with defaults from the mission."""
    k = mission.kinematics
    turn_radius = k.speed / (math.radians(k.turn_limit_deg) / k.step)
    grid = k.mode == "grid"
    return (
        ParamSpec("cruise_speed", "AIRSPEED_CRUISE", "FW_AIRSPD_TRIM", k.speed, 1.0, 100.0, True),
        ParamSpec("airspeed_min", "AIRSPEED_MIN", "FW_AIRSPD_MIN", round(0.5 * k.speed, 1), 1.0, 100.0),
        ParamSpec("airspeed_max", "AIRSPEED_MAX", "FW_AIRSPD_MAX", round(1.5 * k.speed, 1), 1.0, 100.0),
        ParamSpec("turn_limit", "SIM_TURN_LIMIT", "SIM_TURN_LIMIT", k.turn_limit_deg,
                  45.0 if grid else 1.0, 180.0),
        ParamSpec("roll_limit", "ROLL_LIMIT_DEG", "FW_R_LIM", ROLL_LIMIT_DEG, 5.0, 85.0,
                  px4_default=PX4_ROLL_LIMIT_DEG),
        ParamSpec("guided_timeout", "SIM_GUIDED_TMO", "COM_OF_LOSS_T", mission.sim.guided_timeout,
                  0.1, 600.0, px4_default=PX4_OFFBOARD_LOSS_S),
        ParamSpec("wp_radius", "WP_RADIUS", "NAV_ACC_RAD",
                  round(max(mission.region.cell_size, 30.0), 1), 1.0, 1000.0,
                  px4_default=PX4_ACCEPTANCE_RADIUS),
        ParamSpec("loiter_radius", "WP_LOITER_RAD", "NAV_LOITER_RAD",
                  round(max(60.0, 1.5 * turn_radius), 1), 10.0, 5000.0, px4_default=PX4_LOITER_RADIUS),
        ParamSpec("fence_enable", "FENCE_ENABLE", None, 0.0, 0.0, 1.0),
        ParamSpec("fence_action", "FENCE_ACTION", None, 1.0, 0.0, 1.0),
        ParamSpec("fence_type", "FENCE_TYPE", None, 4.0, 0.0, 15.0),
        # ArduPlane's GCS failsafe (sim_vehicles.vehicle), with ArduPlane's defaults
        ParamSpec("gcs_failsafe", "FS_GCS_ENABL", None, 0.0, 0.0, 3.0),
        ParamSpec("gcs_sysid", "MAV_GCS_SYSID", None, 255.0, 1.0, 255.0),
        ParamSpec("short_action", "FS_SHORT_ACTN", None, 0.0, 0.0, 4.0),
        ParamSpec("short_timeout", "FS_SHORT_TIMEOUT", None, 1.5, 1.0, 100.0),
        ParamSpec("long_action", "FS_LONG_ACTN", None, 0.0, 0.0, 4.0),
        ParamSpec("long_timeout", "FS_LONG_TIMEOUT", None, 5.0, 1.0, 300.0),
        ParamSpec("geofence_action", None, "GF_ACTION", PX4_GEOFENCE_HOLD, 0.0, 5.0, integer=True),
        ParamSpec("offboard_loss_action", None, "COM_OBL_RC_ACT", 0.0, 0.0, 7.0, integer=True),
        # the return's altitude above home (ArduPlane 4.5 on: -1 keeps the altitude; PX4: the lowest)
        ParamSpec("rtl_altitude", "RTL_ALTITUDE", "RTL_RETURN_ALT", RTL_ALTITUDE_M, -1.0, 5000.0),
        ParamSpec("rtl_descend_altitude", None, "RTL_DESCEND_ALT", PX4_RTL_DESCEND_M, 2.0, 5000.0),
    )


class ParamStore:
    """Current parameter values of one vehicle, addressed by flavour name or index."""

    def __init__(self, specs: tuple[ParamSpec, ...], flavour: str, grid: bool) -> None:
        px4 = flavour == "px4"
        self.specs = tuple(s for s in specs if (s.px4 if px4 else s.ardupilot) is not None)
        self.names = [str(s.px4 if px4 else s.ardupilot) for s in self.specs]
        self.values = {s.key: float(s.default) for s in self.specs}
        if px4:
            self.values |= {s.key: float(s.px4_default) for s in self.specs if s.px4_default is not None}
        self.grid, self.px4 = grid, px4

    def value(self, key: str, default: float | None = None) -> float:
        """The value of `key`; `default` if the flavour does not have it (KeyError without one)."""
        if default is not None and key not in self.values:
            return default
        return self.values[key]

    def index_of(self, name: str) -> int | None:
        return self.names.index(name) if name in self.names else None

    def set(self, index: int, value: float) -> bool:
        """Set parameter `index`; False (unchanged) if out of range or pinned by the kinematics."""
        spec = self.specs[index]
        if not (math.isfinite(value) and spec.lo <= value <= spec.hi):
            return False
        if spec.integer and value != round(value):
            return False
        if spec.fixed_in_grid and self.grid and value != self.values[spec.key]:
            return False
        self.values[spec.key] = float(value)
        return True

    def bytewise(self, index: int) -> bool:
        """Whether parameter `index` travels as INT32 bytes (the PX4 flavour's integers)."""
        return self.px4 and self.specs[index].integer

    def message(self, index: int) -> mavlink.MAVLink_param_value_message:
        value = self.values[self.specs[index].key]
        kind = mavlink.MAV_PARAM_TYPE_REAL32
        if self.bytewise(index):
            value, kind = _int_bytes(round(value)), mavlink.MAV_PARAM_TYPE_INT32
        return mavlink.MAVLink_param_value_message(
            self.names[index].encode(), value, kind, len(self.specs), index,
        )


def _int_bytes(value: int) -> float:
    return struct.unpack("<f", struct.pack("<i", value))[0]


def _bytes_int(value: float) -> int:
    return struct.unpack("<i", struct.pack("<f", value))[0]


def handle_param(hv: HostedVehicle, msg: mavlink.MAVLink_message, addr: Address) -> None:
    """PARAM_REQUEST_LIST / PARAM_REQUEST_READ (answered to the sender) and PARAM_SET (to all)."""
    store = hv.vehicle.params
    kind = msg.get_type()
    if kind == "PARAM_REQUEST_LIST":
        for i in range(len(store.names)):
            hv.reply(store.message(i), addr)
        return
    if kind == "PARAM_REQUEST_READ" and 0 <= msg.param_index < len(store.names):
        index: int | None = msg.param_index
    else:
        index = store.index_of(msg.param_id)
    if index is None:
        hv.stats.rejected += 1  # ArduPilot ignores unknown names too
        return
    if kind == "PARAM_REQUEST_READ":
        hv.reply(store.message(index), addr)
        return
    value = float(msg.param_value)
    if store.bytewise(index) and msg.param_type == mavlink.MAV_PARAM_TYPE_INT32:
        value = float(_bytes_int(msg.param_value))
    if not hv.vehicle.set_param(index, value):
        hv.stats.rejected += 1
        hv.vehicle.say(f"{store.names[index]}: {value:g} refused", mavlink.MAV_SEVERITY_WARNING)
    hv.broadcast(store.message(index))
