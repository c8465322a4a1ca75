"""COMMAND_LONG / COMMAND_INT: every command gets a COMMAND_ACK with a real autopilot's result.

Unknown commands are answered MAV_RESULT_UNSUPPORTED, arguments out of range MAV_RESULT_DENIED,
commands not possible in the current state MAV_RESULT_FAILED (as ArduPilot does) or
MAV_RESULT_TEMPORARILY_REJECTED (PX4 OFFBOARD without a setpoint stream).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.contracts.frames import yaw_to_heading
from sim_vehicles.telemetry import DEFAULT_RATES_HZ

if TYPE_CHECKING:
    from sim_vehicles.hosted_vehicle import HostedVehicle
    from sim_vehicles.mavlink_endpoint import Address

M = mavlink
LOCKSTEP_COMMAND = M.MAV_CMD_USER_1  # 31010: "lockstep: ready for step param1"
MAX_RANGE_M = 100_000.0  # targets farther than this from the origin are refused
_INT32_MAX = 2**31 - 1


@dataclass(frozen=True)
class Command:
    """A COMMAND_LONG or COMMAND_INT, normalised: lat/lon in degrees in p5/p6 (NaN if unset)."""

    command: int
    p: tuple[float, float, float, float, float, float, float]  # p[0] is param1
    frame: int


def from_message(msg: mavlink.MAVLink_message) -> Command:
    if msg.get_type() == "COMMAND_INT":
        lat = math.nan if msg.x == _INT32_MAX else msg.x * 1e-7
        lon = math.nan if msg.y == _INT32_MAX else msg.y * 1e-7
        p = (msg.param1, msg.param2, msg.param3, msg.param4, lat, lon, msg.z)
        return Command(msg.command, p, msg.frame)
    p = (msg.param1, msg.param2, msg.param3, msg.param4, msg.param5, msg.param6, msg.param7)
    return Command(msg.command, p, M.MAV_FRAME_GLOBAL_RELATIVE_ALT)  # ArduPilot's conversion


def handle_command(hv: HostedVehicle, msg: mavlink.MAVLink_message, addr: Address) -> None:
    """Execute a command and acknowledge it to its sender; send any message it asked for."""
    cmd = from_message(msg)
    handler = HANDLERS.get(cmd.command)
    follow_up: list[int] = []
    if handler is None:
        result = M.MAV_RESULT_UNSUPPORTED
        hv.stats.unhandled += 1
    else:
        result = handler(hv, cmd, addr, follow_up)
        if result == M.MAV_RESULT_DENIED:
            hv.stats.rejected += 1
    hv.reply(
        M.MAVLink_command_ack_message(cmd.command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent()),
        addr,
    )
    for msgid in follow_up:
        hv.reply(hv.build(msgid), addr)


Handler = Callable[["HostedVehicle", Command, "Address", list[int]], int]


def _arm(hv: HostedVehicle, c: Command, addr: Address, follow: list[int]) -> int:
    if c.p[0] not in (0.0, 1.0):
        return M.MAV_RESULT_DENIED
    return hv.vehicle.arm(c.p[0] == 1.0)


def _set_mode(hv: HostedVehicle, c: Command, addr: Address, follow: list[int]) -> int:
    if not all(math.isfinite(v) and v >= 0 for v in c.p[:3]) or not int(c.p[0]) & 1:
        return M.MAV_RESULT_DENIED
    custom = hv.vehicle.flavour.custom_from_do_set_mode(c.p[1], c.p[2])
    return hv.set_mode(custom)


def _mode_named(name: str) -> Handler:
    def handler(hv: HostedVehicle, c: Command, addr: Address, follow: list[int]) -> int:
        return hv.set_mode(hv.vehicle.flavour.by_name(getattr(hv.vehicle.flavour, name)).custom_mode)

    return handler


def _mission_start(hv: HostedVehicle, c: Command, addr: Address, follow: list[int]) -> int:
    auto = next(m for m in hv.vehicle.flavour.modes if m.behaviour.value == "auto")
    result = hv.set_mode(auto.custom_mode)
    if result == M.MAV_RESULT_ACCEPTED and math.isfinite(c.p[0]) and c.p[0] > 0:
        hv.vehicle.set_current(int(c.p[0]))
    return result


def _reposition(hv: HostedVehicle, c: Command, addr: Address, follow: list[int]) -> int:
    lat, lon, alt = c.p[4], c.p[5], c.p[6]
    x, y, _, _ = hv.position()
    target: tuple[float, float] | None
    if math.isnan(lat) and math.isnan(lon):
        target = (x, y)
    else:
        target = hv.local_target(lat, lon)
        if target is None:
            return M.MAV_RESULT_DENIED
    px4 = hv.vehicle.flavour.name == "px4"
    ok, up = hv.altitude(alt, M.MAV_FRAME_GLOBAL if px4 else c.frame)  # PX4: AMSL whatever the frame
    if not ok:
        return M.MAV_RESULT_DENIED
    radius = c.p[2] if math.isfinite(c.p[2]) else 0.0
    flags = int(c.p[1]) if math.isfinite(c.p[1]) else 0
    change_mode = bool(flags & M.MAV_DO_REPOSITION_FLAGS_CHANGE_MODE)
    return hv.vehicle.reposition(x, y, target, up, radius, change_mode)


def _change_heading(hv: HostedVehicle, c: Command, addr: Address, follow: list[int]) -> int:
    if hv.vehicle.flavour.name != "ardupilot":
        return M.MAV_RESULT_UNSUPPORTED
    kind, deg, accel = c.p[0], c.p[1], c.p[2]
    if kind not in (0.0, 1.0, 2.0) or (kind != 2.0 and not (math.isfinite(deg) and 0 <= deg <= 360)):
        return M.MAV_RESULT_DENIED
    x, y, _, _ = hv.position()
    heading = yaw_to_heading(math.radians(deg)) if kind != 2.0 else 0.0
    accel = accel if math.isfinite(accel) else 0.0
    return hv.vehicle.change_heading(hv.t, x, y, int(kind), heading, accel)


def _change_altitude(hv: HostedVehicle, c: Command, addr: Address, follow: list[int]) -> int:
    if hv.vehicle.flavour.name != "ardupilot":
        return M.MAV_RESULT_UNSUPPORTED
    ok, up = hv.altitude(c.p[6], c.frame)
    if not ok or up is None:
        return M.MAV_RESULT_DENIED
    return hv.vehicle.change_altitude(up)


def _fence_enable(hv: HostedVehicle, c: Command, addr: Address, follow: list[int]) -> int:
    store = hv.vehicle.params
    index = store.index_of("FENCE_ENABLE") if hv.vehicle.flavour.name == "ardupilot" else None
    if index is None:
        return M.MAV_RESULT_UNSUPPORTED
    if c.p[0] not in (0.0, 1.0):
        return M.MAV_RESULT_DENIED
    hv.vehicle.set_param(index, c.p[0])
    hv.broadcast(store.message(index))
    return M.MAV_RESULT_ACCEPTED


def _change_speed(hv: HostedVehicle, c: Command, addr: Address, follow: list[int]) -> int:
    if not math.isfinite(c.p[1]):
        return M.MAV_RESULT_DENIED
    return hv.vehicle.change_speed(c.p[1])


def _guided_change_speed(hv: HostedVehicle, c: Command, addr: Address, follow: list[int]) -> int:
    if hv.vehicle.flavour.name != "ardupilot":
        return M.MAV_RESULT_UNSUPPORTED
    if hv.vehicle.mode.behaviour.value != "guided":
        return M.MAV_RESULT_FAILED
    return _change_speed(hv, c, addr, follow)


def _request_message(hv: HostedVehicle, c: Command, addr: Address, follow: list[int]) -> int:
    msgid = int(c.p[0]) if math.isfinite(c.p[0]) else -1
    if msgid not in hv.telemetry.builders:
        return M.MAV_RESULT_UNSUPPORTED
    follow.append(msgid)
    return M.MAV_RESULT_ACCEPTED


def _capabilities(hv: HostedVehicle, c: Command, addr: Address, follow: list[int]) -> int:
    follow.append(M.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
    return M.MAV_RESULT_ACCEPTED


def _home(hv: HostedVehicle, c: Command, addr: Address, follow: list[int]) -> int:
    follow.append(M.MAVLINK_MSG_ID_HOME_POSITION)
    return M.MAV_RESULT_ACCEPTED


def _message_interval(hv: HostedVehicle, c: Command, addr: Address, follow: list[int]) -> int:
    msgid = int(c.p[0]) if math.isfinite(c.p[0]) else -1
    if msgid not in DEFAULT_RATES_HZ:
        return M.MAV_RESULT_UNSUPPORTED
    return M.MAV_RESULT_ACCEPTED if hv.streams.set_interval(msgid, c.p[1]) else M.MAV_RESULT_DENIED


def _lockstep(hv: HostedVehicle, c: Command, addr: Address, follow: list[int]) -> int:
    return hv.lockstep_report(c.p[0], addr)


HANDLERS: dict[int, Handler] = {
    M.MAV_CMD_COMPONENT_ARM_DISARM: _arm,
    M.MAV_CMD_DO_SET_MODE: _set_mode,
    M.MAV_CMD_NAV_RETURN_TO_LAUNCH: _mode_named("rtl"),
    M.MAV_CMD_NAV_LOITER_UNLIM: _mode_named("hold"),
    M.MAV_CMD_MISSION_START: _mission_start,
    M.MAV_CMD_DO_REPOSITION: _reposition,
    M.MAV_CMD_GUIDED_CHANGE_HEADING: _change_heading,
    M.MAV_CMD_GUIDED_CHANGE_ALTITUDE: _change_altitude,
    M.MAV_CMD_DO_FENCE_ENABLE: _fence_enable,
    M.MAV_CMD_DO_CHANGE_SPEED: _change_speed,
    M.MAV_CMD_GUIDED_CHANGE_SPEED: _guided_change_speed,
    M.MAV_CMD_REQUEST_MESSAGE: _request_message,
    M.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES: _capabilities,
    M.MAV_CMD_GET_HOME_POSITION: _home,
    M.MAV_CMD_SET_MESSAGE_INTERVAL: _message_interval,
    LOCKSTEP_COMMAND: _lockstep,
}
