"""One hosted vehicle: its endpoint, streams and protocols, and the messages it acts on.

The context the protocol handlers (`sim_vehicles.protocols`) use: pose and telemetry now, replies
and broadcasts, and the checks of commanded positions and altitudes.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from sim_vehicles.clock import LockstepClock
from sim_vehicles.mavlink_endpoint import Address, MavlinkEndpoint
from sim_vehicles.protocols import ftp
from sim_vehicles.protocols.commands import MAX_RANGE_M, handle_command
from sim_vehicles.protocols.mission import MissionProtocol
from sim_vehicles.protocols.params import handle_param
from sim_vehicles.telemetry import Pose, Streams, TelemetryBuilder
from sim_vehicles.vehicle import Vehicle

from pymavlink.dialects.v20 import ardupilotmega as mavlink  # isort: skip

if TYPE_CHECKING:
    from sim_vehicles.host import Host

M = mavlink
STATS_TEXT_INTERVAL = 5.0  # wall s between "bad input" STATUSTEXTs of one vehicle
RELATIVE_FRAMES = (
    M.MAV_FRAME_GLOBAL_RELATIVE_ALT,
    M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
    M.MAV_FRAME_GLOBAL_TERRAIN_ALT,
    M.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT,  # flat terrain at home
)
AMSL_FRAMES = (M.MAV_FRAME_GLOBAL, M.MAV_FRAME_GLOBAL_INT)
SILENT = frozenset({"HEARTBEAT", "SYSTEM_TIME", "RADIO_STATUS", "MISSION_ACK"})
# a companion's reports to the ground station: routed to the other peers (`route`), not acted on
ROUTED_ONLY = frozenset({
    "STATUSTEXT", "NAMED_VALUE_FLOAT", "ADSB_VEHICLE", "CAMERA_TRACKING_GEO_STATUS",
})  # fmt: skip
NOT_ROUTED = frozenset({M.MAVLINK_MSG_ID_RADIO, M.MAVLINK_MSG_ID_RADIO_STATUS})  # as ArduPilot: a link's own


class HostedVehicle:
    """A vehicle with its endpoint, streams and protocols: the context protocol handlers use."""

    def __init__(self, host: Host, index: int, vehicle: Vehicle, endpoint: MavlinkEndpoint) -> None:
        self.host, self.index, self.vehicle, self.endpoint = host, index, vehicle, endpoint
        self.frame = host.frame
        self.streams = Streams()
        self.telemetry = TelemetryBuilder(host.frame, vehicle, host.unix_epoch_usec)
        self.missions = MissionProtocol()
        self.stats = endpoint.stats
        self._pose_tick = -1
        self._pose: Pose | None = None
        self._stats_reported = (0, 0, 0)
        self._stats_said = -math.inf
        self.routes: dict[int, Address] = {}  # system id -> the peer it was last heard from

    @property
    def t(self) -> float:
        return self.host.t

    def position(self) -> tuple[float, float, float, float]:
        """(x, y, heading, up) now."""
        f, i = self.host.flight, self.index
        return float(f.x[i]), float(f.y[i]), float(f.heading[i]), float(f.alt[i])

    def pose(self) -> Pose:
        if self._pose is None or self._pose_tick != self.host.tick:
            f, i = self.host.flight, self.index
            x, y, h, up = self.position()
            lat, lon, alt = self.frame.to_geodetic(x, y, up)
            self._pose = Pose(
                x, y, h, up, float(f.vx[i]), float(f.vy[i]), float(f.vz[i]), float(f.omega[i]),
                float(f.roll[i]), lat, lon, alt,
            )
            self._pose_tick = self.host.tick
        return self._pose

    def build(self, msgid: int) -> mavlink.MAVLink_message:
        self.telemetry.errors = (self.stats.bad_frames, self.stats.unhandled, self.stats.rejected)
        return self.telemetry.build(msgid, self.t, self.pose())

    def reply(self, msg: mavlink.MAVLink_message, addr: Address) -> None:
        self.endpoint.send(msg, addr)

    def broadcast(self, msg: mavlink.MAVLink_message) -> None:
        self.endpoint.send(msg)

    # ---- helpers for the protocol handlers ----------------------------------------------
    def set_mode(self, custom_mode: int) -> int:
        x, y, _, _ = self.position()
        before = self.vehicle.mode
        result = self.vehicle.set_mode(custom_mode, self.t, x, y)
        if self.vehicle.mode != before:
            self.broadcast(self.build(M.MAVLINK_MSG_ID_HEARTBEAT))
        return result

    def local_target(self, lat: float, lon: float) -> tuple[float, float] | None:
        """Local (x, y) of a commanded lat/lon; None if invalid or farther than MAX_RANGE_M."""
        if not (math.isfinite(lat) and math.isfinite(lon) and -90 <= lat <= 90 and -180 <= lon <= 180):
            return None
        if lat == 0 and lon == 0:
            return None
        x, y = self.frame.to_local(lat, lon)
        return (x, y) if math.hypot(x, y) <= MAX_RANGE_M else None

    def altitude(self, alt: float, frame: int) -> tuple[bool, float | None]:
        """(valid, metres above home) of a commanded altitude; NaN keeps the altitude (None)."""
        if math.isnan(alt):
            return True, None
        if not math.isfinite(alt):
            return False, None
        if frame in RELATIVE_FRAMES:
            return True, alt
        if frame in AMSL_FRAMES:
            return True, alt - self.frame.alt0
        return False, None

    def lockstep_report(self, step: float, addr: Address) -> int:
        clock = self.host.clock
        if not isinstance(clock, LockstepClock):
            return M.MAV_RESULT_UNSUPPORTED
        result, snapshot = clock.report(self.index, step)
        if snapshot:
            self.host.pending_snapshots.add(self.index)
        return result

    # ---- inbound ------------------------------------------------------------------------
    def route(self, msg: mavlink.MAVLink_message, addr: Address) -> None:
        """Forward what is not for this vehicle alone to its other peers, as ArduPilot routes its links.

        No target system (or 0): to every other peer; another system: to the peer that system was
        last heard from; this vehicle: kept. The frame goes as it came, its signature included.
        """
        self.routes[msg.get_srcSystem()] = addr
        if msg.get_msgId() in NOT_ROUTED:
            return
        target = getattr(msg, "target_system", 0)
        if target == self.vehicle.sysid:
            return
        if target == 0:
            peers = [a for a in self.endpoint.peers if a != addr]
        else:
            to = self.routes.get(target)
            peers = [to] if to is not None and to != addr else []
        for peer in peers:
            self.endpoint.forward(msg.get_msgbuf(), peer)

    def handle(self, msg: mavlink.MAVLink_message, addr: Address) -> None:
        target = getattr(msg, "target_system", 0)
        if target not in (0, self.vehicle.sysid) or getattr(msg, "target_component", 0) not in (0, 1):
            return
        kind = msg.get_type()
        if kind in ("COMMAND_LONG", "COMMAND_INT"):
            handle_command(self, msg, addr)
        elif kind.startswith("PARAM_") and kind in ("PARAM_REQUEST_LIST", "PARAM_REQUEST_READ", "PARAM_SET"):
            handle_param(self, msg, addr)
        elif kind.startswith("MISSION_") and kind != "MISSION_ACK":
            self.missions.handle(self, msg, addr)
        elif kind == "SET_MODE":
            result = self.set_mode(msg.custom_mode) if msg.base_mode & 1 else M.MAV_RESULT_DENIED
            self.reply(M.MAVLink_command_ack_message(M.MAVLINK_MSG_ID_SET_MODE, result), addr)
        elif kind == "REQUEST_DATA_STREAM":
            if not self.streams.set_stream(msg.req_stream_id, msg.req_message_rate, bool(msg.start_stop)):
                self.stats.unhandled += 1
        elif kind in ("SET_POSITION_TARGET_GLOBAL_INT", "SET_POSITION_TARGET_LOCAL_NED"):
            self._position_target(msg)
        elif kind == "SET_ATTITUDE_TARGET":
            self._attitude_target(msg)
        elif kind == "FILE_TRANSFER_PROTOCOL":
            payload = ftp.nak_payload(bytes(msg.payload))
            if payload is None:
                self.stats.rejected += 1
            else:
                self.reply(
                    M.MAVLink_file_transfer_protocol_message(
                        0, msg.get_srcSystem(), msg.get_srcComponent(), payload
                    ),
                    addr,
                )
        elif kind == "HEARTBEAT":
            self.vehicle.heartbeat(self.t, msg.get_srcSystem())
        elif kind == "TIMESYNC":
            if msg.tc1 == 0:
                self.reply(M.MAVLink_timesync_message(round(self.t * 1e9), msg.ts1), addr)
        elif kind not in SILENT and kind not in ROUTED_ONLY:
            self.stats.unhandled += 1

    def _position_target(self, msg: mavlink.MAVLink_message) -> None:
        mask = msg.type_mask
        target = up = None
        if msg.get_type() == "SET_POSITION_TARGET_GLOBAL_INT":
            if not mask & 3:
                target = self.local_target(msg.lat_int * 1e-7, msg.lon_int * 1e-7)
                if target is None:
                    self.stats.rejected += 1
                    return
            if not mask & 4:
                ok, up = self.altitude(msg.alt, msg.coordinate_frame)
                if not ok:
                    self.stats.rejected += 1
                    return
        else:
            if msg.coordinate_frame != M.MAV_FRAME_LOCAL_NED:
                self.stats.unhandled += 1
                return
            if not mask & 3 and math.isfinite(msg.x + msg.y):
                target = (msg.y, msg.x)
            if not mask & 4 and math.isfinite(msg.z):
                up = -msg.z
        self.vehicle.position_target(self.t, target, up)

    def _attitude_target(self, msg: mavlink.MAVLink_message) -> None:
        if msg.type_mask & M.ATTITUDE_TARGET_TYPEMASK_BODY_YAW_RATE_IGNORE:
            self.stats.unhandled += 1
            return
        if not math.isfinite(msg.body_yaw_rate):
            self.stats.rejected += 1
            return
        self.vehicle.turn_rate(self.t, -msg.body_yaw_rate)  # MAVLink yaw rate is clockwise

    # ---- outbound -----------------------------------------------------------------------
    def flush(self) -> None:
        """Send the vehicle's pending STATUSTEXTs and MISSION_ITEM_REACHEDs."""
        v = self.vehicle
        for severity, text in v.texts:
            self.broadcast(M.MAVLink_statustext_message(severity, text.encode()[:50]))
        for seq in v.reached:
            self.broadcast(M.MAVLink_mission_item_reached_message(seq))
        v.texts.clear()
        v.reached.clear()

    def report_bad_input(self, wall: float) -> None:
        s = self.stats
        counts = (s.bad_frames, s.rejected, s.unsigned + s.bad_signature)
        if counts != self._stats_reported and wall - self._stats_said >= STATS_TEXT_INTERVAL:
            unsigned = f", {counts[2]} unsigned or badly signed" if self.endpoint.signing else ""
            self.vehicle.say(
                f"Bad input: {counts[0]} bad frames, {counts[1]} rejected values{unsigned}",
                M.MAV_SEVERITY_NOTICE,
            )
            self._stats_reported, self._stats_said = counts, wall
            self.flush()
