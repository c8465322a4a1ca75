"""The MAVLink mission protocol: upload, download, clear, set current, for missions and fences.

ArduPilot flavour keeps home as item 0 (an "empty" mission downloads as one item, home, and an
uploaded item 0 is replaced by home); PX4 flavour has no such item. Both store a fence (mission
type FENCE): its inclusion and exclusion polygons (MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION or
_EXCLUSION items, param1 = the polygon's vertex count) and circles (param1 = the radius) are what the
vehicle enforces (`sim_vehicles.fence`); a return point is stored and downloaded only. Rally
lists are always empty: downloads report 0 items, uploads of items are refused with
MAV_MISSION_UNSUPPORTED. The vehicle drives
uploads (MISSION_REQUEST_INT per item); the client retries lost messages.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from sim_vehicles.fence import Fence, FencePoint, parse_fence
from sim_vehicles.nav_targets import Waypoint

if TYPE_CHECKING:
    from sim_vehicles.hosted_vehicle import HostedVehicle
    from sim_vehicles.mavlink_endpoint import Address

M = mavlink
MAX_ITEMS = 500
POSITION_COMMANDS = (
    M.MAV_CMD_NAV_WAYPOINT, M.MAV_CMD_NAV_LOITER_UNLIM, M.MAV_CMD_NAV_LOITER_TURNS,
    M.MAV_CMD_NAV_LOITER_TIME,
)
FENCE_COMMANDS = (
    M.MAV_CMD_NAV_FENCE_RETURN_POINT, M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION,
    M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION, M.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION,
    M.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION,
)
RELATIVE_FRAMES = (M.MAV_FRAME_GLOBAL_RELATIVE_ALT, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT)
GLOBAL_FRAMES = (
    M.MAV_FRAME_GLOBAL, M.MAV_FRAME_GLOBAL_INT, M.MAV_FRAME_GLOBAL_RELATIVE_ALT,
    M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, M.MAV_FRAME_GLOBAL_TERRAIN_ALT, M.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT,
)


@dataclass(frozen=True)
class Item:
    """A stored mission item (MISSION_ITEM_INT fields; x, y are degrees * 1e7)."""

    frame: int
    command: int
    autocontinue: int
    params: tuple[float, float, float, float]
    x: int
    y: int
    z: float


@dataclass
class Upload:
    addr: Address
    count: int
    items: list[Item]
    mission_type: int


class MissionProtocol:
    """One vehicle's stored mission and fence, and the transfer in progress."""

    def __init__(self) -> None:
        self.items: list[Item] = []
        self.fence: list[Item] = []
        self.upload: Upload | None = None

    # ---- dispatch -----------------------------------------------------------------------
    def handle(self, hv: HostedVehicle, msg: mavlink.MAVLink_message, addr: Address) -> None:
        kind = msg.get_type()
        mission_type = getattr(msg, "mission_type", M.MAV_MISSION_TYPE_MISSION)
        if kind == "MISSION_REQUEST_LIST":
            count = len(self._download(hv, mission_type))
            hv.reply(M.MAVLink_mission_count_message(*_target(msg), count, mission_type), addr)
        elif kind in ("MISSION_REQUEST_INT", "MISSION_REQUEST"):
            self._send_item(hv, msg, addr, kind == "MISSION_REQUEST_INT")
        elif kind == "MISSION_COUNT":
            self._start_upload(hv, msg, addr)
        elif kind in ("MISSION_ITEM_INT", "MISSION_ITEM"):
            self._receive_item(hv, msg, addr)
        elif kind == "MISSION_CLEAR_ALL":
            if mission_type in (M.MAV_MISSION_TYPE_MISSION, M.MAV_MISSION_TYPE_FENCE):
                self._commit(hv, [], mission_type)
            self._ack(hv, msg, addr, M.MAV_MISSION_ACCEPTED)
        elif kind == "MISSION_SET_CURRENT":
            if hv.vehicle.set_current(msg.seq):
                hv.broadcast(hv.build(M.MAVLINK_MSG_ID_MISSION_CURRENT))
            else:
                hv.stats.rejected += 1
        # MISSION_ACK from a client ends a download: nothing to do.

    # ---- download -----------------------------------------------------------------------
    def _download(self, hv: HostedVehicle, mission_type: int) -> list[Item]:
        if mission_type == M.MAV_MISSION_TYPE_FENCE:
            return self.fence
        if mission_type != M.MAV_MISSION_TYPE_MISSION:
            return []
        if not hv.vehicle.flavour.home_is_item0:
            return self.items
        lat, lon, alt = hv.telemetry.home
        home = Item(M.MAV_FRAME_GLOBAL, M.MAV_CMD_NAV_WAYPOINT, 1, (0, 0, 0, 0),
                    round(lat * 1e7), round(lon * 1e7), alt)
        return [home, *self.items[1:]]

    def _send_item(
        self, hv: HostedVehicle, msg: mavlink.MAVLink_message, addr: Address, as_int: bool
    ) -> None:
        items = self._download(hv, msg.mission_type)
        if not 0 <= msg.seq < len(items):
            hv.stats.rejected += 1
            self._ack(hv, msg, addr, M.MAV_MISSION_INVALID_SEQUENCE)
            return
        it = items[msg.seq]
        current = int(msg.seq == hv.vehicle.current_seq)
        if as_int:
            out = M.MAVLink_mission_item_int_message(
                *_target(msg), msg.seq, it.frame, it.command, current, it.autocontinue, *it.params,
                it.x, it.y, it.z, msg.mission_type,
            )
        else:
            out = M.MAVLink_mission_item_message(
                *_target(msg), msg.seq, it.frame, it.command, current, it.autocontinue, *it.params,
                it.x * 1e-7, it.y * 1e-7, it.z, msg.mission_type,
            )
        hv.reply(out, addr)

    # ---- upload -------------------------------------------------------------------------
    def _start_upload(self, hv: HostedVehicle, msg: mavlink.MAVLink_message, addr: Address) -> None:
        self.upload = None
        kind = msg.mission_type
        known = (M.MAV_MISSION_TYPE_MISSION, M.MAV_MISSION_TYPE_FENCE, M.MAV_MISSION_TYPE_RALLY)
        stored = (M.MAV_MISSION_TYPE_MISSION, M.MAV_MISSION_TYPE_FENCE)
        if kind not in known:
            self._ack(hv, msg, addr, M.MAV_MISSION_UNSUPPORTED)
        elif msg.count == 0:
            if kind in stored:
                self._commit(hv, [], kind)
            self._ack(hv, msg, addr, M.MAV_MISSION_ACCEPTED)
        elif kind not in stored:
            self._ack(hv, msg, addr, M.MAV_MISSION_UNSUPPORTED)
        elif msg.count > MAX_ITEMS:
            hv.stats.rejected += 1
            self._ack(hv, msg, addr, M.MAV_MISSION_NO_SPACE)
        else:
            self.upload = Upload(addr, msg.count, [], kind)
            self._request(hv, msg, addr, 0)

    def _receive_item(self, hv: HostedVehicle, msg: mavlink.MAVLink_message, addr: Address) -> None:
        if msg.current == 2 and hv.vehicle.flavour.name == "ardupilot":  # ArduPilot guided waypoint
            self._guided_waypoint(hv, msg, addr)
            return
        up = self.upload
        if up is None or addr != up.addr or msg.mission_type != up.mission_type:
            hv.stats.unhandled += 1
            return
        expected = len(up.items)
        if msg.seq < expected:
            self._request(hv, msg, addr, expected)  # a duplicate: ask again for the one we need
            return
        if msg.seq > expected:
            self.upload = None
            self._ack(hv, msg, addr, M.MAV_MISSION_INVALID_SEQUENCE)
            return
        item, error = _validate(msg)
        if item is None:
            hv.stats.rejected += 1
            self.upload = None
            self._ack(hv, msg, addr, error)
            return
        up.items.append(item)
        if len(up.items) < up.count:
            self._request(hv, msg, addr, len(up.items))
            return
        self.upload = None
        if up.mission_type == M.MAV_MISSION_TYPE_FENCE and _fence(hv, up.items) is None:
            hv.stats.rejected += 1
            self._ack(hv, msg, addr, M.MAV_MISSION_INVALID)
            return
        self._commit(hv, up.items, up.mission_type)
        self._ack(hv, msg, addr, M.MAV_MISSION_ACCEPTED)

    def _guided_waypoint(self, hv: HostedVehicle, msg: mavlink.MAVLink_message, addr: Address) -> None:
        item, error = _validate(msg)
        result = M.MAV_MISSION_ERROR
        if item is not None:
            target = hv.local_target(item.x * 1e-7, item.y * 1e-7)
            ok, up = hv.altitude(item.z, item.frame)
            x, y, _, _ = hv.position()
            if target is not None and ok and hv.vehicle.reposition(x, y, target, up, 0.0, False) == 0:
                result = M.MAV_MISSION_ACCEPTED
        else:
            result = error
        self._ack(hv, msg, addr, result)

    def _commit(self, hv: HostedVehicle, items: list[Item], mission_type: int) -> None:
        if mission_type == M.MAV_MISSION_TYPE_FENCE:
            self.fence = list(items)
            hv.vehicle.set_fence(_fence(hv, items) or Fence())
            return
        self.items = list(items)
        first = 1 if hv.vehicle.flavour.home_is_item0 else 0
        waypoints = []
        for seq, it in enumerate(items[first:], start=first):
            if it.command == M.MAV_CMD_NAV_RETURN_TO_LAUNCH:
                waypoints.append(Waypoint(seq, it.command, math.nan, math.nan, None))
            elif it.command in POSITION_COMMANDS:
                # ArduPilot: latitude and longitude 0 mean where the vehicle is when the item starts,
                # a relative altitude 0 its altitude then
                here = hv.vehicle.flavour.home_is_item0 and it.x == 0 and it.y == 0
                x, y = (math.nan, math.nan) if here else hv.frame.to_local(it.x * 1e-7, it.y * 1e-7)
                _, up = hv.altitude(it.z, it.frame)
                if up == 0 and it.frame in RELATIVE_FRAMES and hv.vehicle.flavour.home_is_item0:
                    up = None
                radius = it.params[2] if it.command == M.MAV_CMD_NAV_LOITER_UNLIM else 0.0
                waypoints.append(Waypoint(seq, it.command, x, y, up, here, radius))
        hv.vehicle.set_mission(waypoints)

    def _request(self, hv: HostedVehicle, msg: mavlink.MAVLink_message, addr: Address, seq: int) -> None:
        hv.reply(M.MAVLink_mission_request_int_message(*_target(msg), seq, msg.mission_type), addr)

    def _ack(self, hv: HostedVehicle, msg: mavlink.MAVLink_message, addr: Address, result: int) -> None:
        mission_type = getattr(msg, "mission_type", M.MAV_MISSION_TYPE_MISSION)
        hv.reply(M.MAVLink_mission_ack_message(*_target(msg), result, mission_type), addr)


def _target(msg: mavlink.MAVLink_message) -> tuple[int, int]:
    """(target_system, target_component) of a reply to `msg`."""
    return msg.get_srcSystem(), msg.get_srcComponent()


def _validate(msg: mavlink.MAVLink_message) -> tuple[Item | None, int]:
    """The item of a MISSION_ITEM(_INT), or None and the MAV_MISSION_RESULT refusing it."""
    if msg.get_type() == "MISSION_ITEM_INT":
        x, y = msg.x, msg.y
    else:
        if not (math.isfinite(msg.x) and math.isfinite(msg.y)):
            return None, M.MAV_MISSION_INVALID_PARAM5_X
        x, y = round(msg.x * 1e7), round(msg.y * 1e7)
    if msg.command in POSITION_COMMANDS + FENCE_COMMANDS:
        if msg.frame not in GLOBAL_FRAMES:
            return None, M.MAV_MISSION_UNSUPPORTED_FRAME
        if not -90e7 <= x <= 90e7:
            return None, M.MAV_MISSION_INVALID_PARAM5_X
        if not -180e7 <= y <= 180e7:
            return None, M.MAV_MISSION_INVALID_PARAM6_Y
    if not math.isfinite(msg.z) and msg.command in POSITION_COMMANDS:
        return None, M.MAV_MISSION_INVALID_PARAM7
    params = (msg.param1, msg.param2, msg.param3, msg.param4)
    return Item(msg.frame, msg.command, msg.autocontinue, params, x, y, msg.z), M.MAV_MISSION_ACCEPTED


def _fence(hv: HostedVehicle, items: list[Item]) -> Fence | None:
    """The zones of a fence's items (local frame); None if malformed (`sim_vehicles.fence.parse_fence`)."""
    points = [FencePoint(it.command, it.params[0], it.x, it.y) for it in items]
    return parse_fence(points, hv.frame.to_local)
