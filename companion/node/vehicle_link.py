"""The companion's MAVLink link to its autopilot: telemetry in, guidance out (pymavlink).

Any pymavlink connection string works (udp, udpin, udpout, tcp, serial). The link waits for the
autopilot's HEARTBEAT, asks for the telemetry it needs at the rates it needs, keeps the latest
vehicle state (pose in the mission's local frame, mode, armed flag, vehicle time) and records a
.tlog of everything it receives and sends. It speaks as the vehicle's own system id, or as a system
id of its own (the companion's `COMPANION_SYSTEM`, which the autopilot's GCS failsafe watches:
`companion.node.failsafe`); with `heartbeat` it sends its HEARTBEAT from `poll` whenever one is
due, in vehicle time and in wall time (also between the messages of a long backlog), so the autopilot
hears it in every phase of the flight.
It never changes the vehicle's mode or arms it unless asked to (`companion.node.takeover`).
Replies to requests (COMMAND_ACK, PARAM_VALUE, the mission protocol's requests and acks) are kept
for the code that waits for them (`await_reply`).

PX4 differs in ways the link hides: its integer parameters travel byte-wise in PARAM_VALUE's float
(ArduPilot casts them), it reads DO_REPOSITION's altitude as AMSL whatever the frame and answers it
UNSUPPORTED without the change-mode flag, and its fixed-wing (the SIH model at least) flies with
sideslip, so on PX4 the heading is the course over ground (GLOBAL_POSITION_INT's velocity) whenever
the vehicle moves, not ATTITUDE's yaw.

With a signing secret (the vehicle's, from the mission's key directory or `--mavlink-key`) every
frame sent is MAVLink2-signed and only frames signed with the same secret are accepted (besides the
radio's RADIO_STATUS), as between ArduPilot and a ground station once signing is set up; rejected
frames are counted in `unauthenticated`. A frame whose signature fails never moves its stream's
timestamp (pymavlink moves it before it checks: one forged frame stamped far ahead would make every
genuine frame after it look like a replay), and pymavlink's own per-frame log lines are silenced.

Once its vehicle's HEARTBEAT is heard, the link takes only what that system's autopilot component
says; frames of other systems or components are counted in `wrong_system`. Every refusal is
counted by kind and sender and logged rate-limited (`refusals`, `companion.node.refusals`).
A `udpout` link to a loopback address sends from (and so is reachable on) loopback only.
"""

from __future__ import annotations

import contextlib
import ipaddress
import logging
import math
import os
import socket
import struct
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.contracts.frames import LocalFrame, yaw_to_heading
from companion.contracts.mavlink_signing import keep_stream_timestamps, signing_timestamp
from companion.node.refusals import Refusals

log = logging.getLogger("companion.link")
logging.getLogger("pymavlink").setLevel(logging.WARNING)  # "old timestamp" once per refused frame

COMPANION_COMPONENT = mavlink.MAV_COMP_ID_ONBOARD_COMPUTER
# The companion's own system id: no ground station (255; MAVSDK 245) or on-board component (the
# vehicle's id) uses it, so the autopilot's GCS failsafe, which knows its GCS by system id only,
# hears the companion alone.
COMPANION_SYSTEM = 200
HEARTBEAT_VEHICLE_S = 0.5  # our HEARTBEAT at least this often in vehicle time (a sped-up simulator)...
HEARTBEAT_WALL_S = 1.0  # ...and in wall time (a vehicle whose clock stands still, a lost link)
RETRY_OPEN_S = 0.5  # a link that cannot be opened yet is tried again this often
VEHICLE_WAIT_S = 120.0  # how long a companion waits for its link to open, and then for its first HEARTBEAT
ARDUPILOT_GUIDED = 15
ARDUPILOT_AUTO = 10
ARDUPILOT_TAKEOFF = 13
PX4_OFFBOARD = 6 << 16
PX4_HOLD = (4 << 16) | (3 << 24)  # AUTO.LOITER
PX4_TAKEOFF = (4 << 16) | (2 << 24)  # AUTO.TAKEOFF
COURSE_MIN_SPEED = 3.0  # m/s: slower than this the heading is ATTITUDE's yaw (PX4)
INTEGER_PARAMS = frozenset(
    {
        mavlink.MAV_PARAM_TYPE_UINT8,
        mavlink.MAV_PARAM_TYPE_INT8,
        mavlink.MAV_PARAM_TYPE_UINT16,
        mavlink.MAV_PARAM_TYPE_INT16,
        mavlink.MAV_PARAM_TYPE_UINT32,
        mavlink.MAV_PARAM_TYPE_INT32,
    }
)

STREAMS_HZ = {
    mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 10.0,
    mavlink.MAVLINK_MSG_ID_ATTITUDE: 10.0,
    mavlink.MAVLINK_MSG_ID_SYS_STATUS: 1.0,
    mavlink.MAVLINK_MSG_ID_SYSTEM_TIME: 1.0,
    mavlink.MAVLINK_MSG_ID_GPS_RAW_INT: 1.0,
}
UNSIGNED_ALLOWED = frozenset({mavlink.MAVLINK_MSG_ID_RADIO_STATUS, mavlink.MAVLINK_MSG_ID_RADIO})
REPLIES = frozenset({"COMMAND_ACK", "PARAM_VALUE", "MISSION_REQUEST", "MISSION_REQUEST_INT", "MISSION_ACK"})


def frame_sender(data: bytes) -> tuple[str, str]:
    """(kind, sender) of a frame refused for its signature: "bad signature" if it was signed,
    "unsigned" if not; the sender as "system S component C" from its header."""
    if len(data) >= 10 and data[0] == 0xFD:
        kind = "bad signature" if data[2] & 1 else "unsigned"
        return kind, f"system {data[5]} component {data[6]}"
    if len(data) >= 6 and data[0] == 0xFE:
        return "unsigned", f"system {data[3]} component {data[4]}"
    return "unsigned", "unknown"


def _loopback(host: str) -> bool:
    try:
        return ipaddress.ip_address(socket.gethostbyname(host)).is_loopback
    except (OSError, ValueError):
        return False


class LinkError(RuntimeError):
    """The vehicle could not be reached."""


class LinkNotOpen(LinkError):
    """The link could not be opened (yet): the reason."""


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


class TlogWriter:
    """MAVLink .tlog: each message prefixed with its big-endian 64-bit microsecond timestamp."""

    def __init__(self, path: Path) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        self._f: BinaryIO = path.open("ab")  # a restarted companion appends

    def write(self, buf: bytes) -> None:
        self._f.write(struct.pack(">Q", int(time.time() * 1e6)) + buf)

    def close(self) -> None:
        self._f.close()


class VehicleLink:
    """One autopilot over MAVLink."""

    def __init__(
        self,
        url: str,
        frame: LocalFrame,
        tlog: Path | None = None,
        component: int = COMPANION_COMPONENT,
        signing_secret: bytes | None = None,
        system: int | None = None,
        heartbeat: bool = False,
    ) -> None:
        """`system`: the link's own system id (None: the vehicle's, once its HEARTBEAT is heard);
        `heartbeat`: `poll` sends our HEARTBEAT whenever one is due."""
        self.url, self.frame = url, frame
        self.state = VehicleState()
        self.rejected = 0
        self.unauthenticated = 0
        self.wrong_system = 0
        self.refusals = Refusals(log, f"MAVLink {url}")
        self.replies: deque[mavlink.MAVLink_message] = deque(maxlen=256)
        self._own_system = system
        self._heartbeat = heartbeat
        self._beat_wall, self._beat_vehicle = -math.inf, -math.inf
        self.param_types: dict[str, int] = {}  # MAV_PARAM_TYPE of every parameter seen
        # Called after every poll, also while a request waits for its reply: what must go on
        # meanwhile (a setpoint stream that PX4 OFFBOARD must not lose).
        self.on_poll: Callable[[], None] | None = None
        try:
            self._conn = mavutil.mavlink_connection(
                url,
                source_system=255 if system is None else system,
                source_component=component,
                autoreconnect=True,
                dialect="ardupilotmega",
            )
        except OSError as exc:  # a TCP port that refuses, no such serial device
            raise LinkNotOpen(str(exc)) from None
        try:
            self._bind_loopback()
            self._tlog = TlogWriter(tlog) if tlog else None
        except OSError:
            self._conn.close()
            raise
        if self._tlog:
            tlog_writer = self._tlog
            self._conn.mav.set_send_callback(lambda m: tlog_writer.write(m.get_msgbuf()))
        if signing_secret is not None:
            self._conn.setup_signing(
                signing_secret,
                sign_outgoing=True,
                allow_unsigned_callback=lambda _mav, msg_id: msg_id in UNSIGNED_ALLOWED,
                link_id=0,
            )
            keep_stream_timestamps(self._conn.mav)

    def _bind_loopback(self) -> None:
        """A udpout link to a loopback address: bind its socket to loopback before it sends (the
        OS would bind it to every interface, where anyone on the network could write to it)."""
        conn = self._conn
        if isinstance(conn, mavutil.mavudp) and not conn.udp_server and _loopback(conn.destination_addr[0]):
            conn.port.bind(("127.0.0.1", 0))

    @property
    def local_address(self) -> tuple[str, int] | None:
        """The address this link receives on (UDP), None for other links or before it is bound."""
        conn = self._conn
        if not isinstance(conn, mavutil.mavudp):
            return None
        host, port = conn.port.getsockname()[:2]
        return (host, port) if port else None

    @property
    def signed(self) -> bool:
        """True when the link signs what it sends and accepts only signed frames."""
        return self._conn.mav.signing.secret_key is not None

    # -- connection --------------------------------------------------------------------------------
    def wait_heartbeat(self, timeout: float, should_stop: Callable[[], bool] = lambda: False) -> bool:
        """Block until the autopilot's HEARTBEAT arrives (sending ours so udpout links open): True;
        False if `should_stop` says so first; LinkError if `timeout` seconds pass first."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if should_stop():
                return False
            self.send_heartbeat()
            self.poll(0.5)
            if self.state.system:
                if self._own_system is None:
                    self._conn.mav.srcSystem = self.state.system
                return True
        raise LinkError(f"no HEARTBEAT from {self.url} within {timeout:.0f} s")

    def request_streams(self, extra: dict[int, float] | None = None) -> None:
        """SET_MESSAGE_INTERVAL for every message the companion needs."""
        for msg_id, hz in {**STREAMS_HZ, **(extra or {})}.items():
            self.command_long(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, msg_id, 1e6 / hz)

    def send_heartbeat(self) -> None:
        self._conn.mav.heartbeat_send(
            mavlink.MAV_TYPE_ONBOARD_CONTROLLER, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, mavlink.MAV_STATE_ACTIVE
        )
        self._beat_wall, self._beat_vehicle = time.monotonic(), self.state.time_s

    def _beat_if_due(self) -> None:
        wall_due = time.monotonic() - self._beat_wall >= HEARTBEAT_WALL_S
        vehicle_due = self.state.time_s - self._beat_vehicle >= HEARTBEAT_VEHICLE_S
        if wall_due or vehicle_due:
            with contextlib.suppress(OSError):  # a TCP vehicle gone: the next poll says so
                self.send_heartbeat()

    def link_alive(self, now: float, timeout: float) -> bool:
        return now - self.state.last_heartbeat <= timeout

    # -- telemetry ---------------------------------------------------------------------------------
    def poll(self, timeout: float) -> int:
        """Read every pending message (waiting up to `timeout` for the first); returns how many."""
        count = 0
        if self._heartbeat:
            self._beat_if_due()
        try:
            msg = self._conn.recv_match(blocking=True, timeout=timeout)
            while msg is not None:
                count += 1
                self._handle(msg)
                if self._heartbeat:  # a long backlog (a loaded machine, a fast vehicle) must not silence us
                    self._beat_if_due()
                msg = self._conn.recv_match(blocking=False)
        except (OSError, ValueError):  # a TCP vehicle gone: pymavlink's reconnect was refused
            time.sleep(timeout)
        if self._heartbeat:
            self._beat_if_due()
        if self.on_poll is not None:
            self.on_poll()
        return count

    def _handle(self, msg: mavlink.MAVLink_message) -> None:
        kind = msg.get_type()
        if kind == "BAD_DATA":
            if "signature" in str(getattr(msg, "reason", "")):
                self.unauthenticated += 1
                self.refusals.refuse(*frame_sender(bytes(getattr(msg, "data", b""))))
            else:
                self.rejected += 1
            return
        if self._tlog:
            self._tlog.write(msg.get_msgbuf())
        s = self.state
        source = (msg.get_srcSystem(), msg.get_srcComponent())
        if s.system and source != (s.system, mavlink.MAV_COMP_ID_AUTOPILOT1):
            if msg.get_msgId() not in UNSIGNED_ALLOWED:  # the radio's own status: not a fault
                self.wrong_system += 1
                self.refusals.refuse("wrong system", f"system {source[0]} component {source[1]}", kind)
            return
        if kind == "HEARTBEAT":
            if msg.get_srcComponent() != mavlink.MAV_COMP_ID_AUTOPILOT1 or msg.type == mavlink.MAV_TYPE_GCS:
                return
            s.system, s.autopilot = msg.get_srcSystem(), msg.autopilot
            s.custom_mode = msg.custom_mode
            s.armed = bool(msg.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
            s.last_heartbeat = time.monotonic()
        elif kind == "GLOBAL_POSITION_INT":
            s.x, s.y = self.frame.to_local(msg.lat * 1e-7, msg.lon * 1e-7)
            s.up = msg.relative_alt * 1e-3
            s.home_amsl = (msg.alt - msg.relative_alt) * 1e-3
            s.moving = s.px4 and math.hypot(msg.vx, msg.vy) * 0.01 >= COURSE_MIN_SPEED
            if s.moving:  # vx north, vy east (cm/s)
                s.heading = math.atan2(msg.vx, msg.vy)
            elif not math.isfinite(s.heading) and msg.hdg != 65535:
                s.heading = yaw_to_heading(math.radians(msg.hdg * 0.01))
            s.time_s = msg.time_boot_ms * 1e-3
        elif kind == "ATTITUDE":
            if not s.moving:
                s.heading = yaw_to_heading(msg.yaw)
            # body yaw rate = heading rate * cos(roll) * cos(pitch) in a level turn; CW positive
            s.turn_rate = -msg.yawspeed / max(math.cos(msg.roll) * math.cos(msg.pitch), 0.2)
        elif kind == "GPS_RAW_INT":
            s.gps_fix = msg.fix_type
        elif kind == "SYS_STATUS":
            bit = mavlink.MAV_SYS_STATUS_PREARM_CHECK
            s.prearm_ok = bool(msg.onboard_control_sensors_present & msg.onboard_control_sensors_health & bit)
        elif kind == "STATUSTEXT":
            s.texts.append(msg.text)
            s.text_count += 1
            del s.texts[:-50]
        elif kind in REPLIES:
            if kind == "PARAM_VALUE":
                self.param_types[msg.param_id] = msg.param_type
            self.replies.append(msg)

    def await_reply(
        self, match: Callable[[mavlink.MAVLink_message], bool], timeout: float
    ) -> mavlink.MAVLink_message | None:
        """The first kept reply that `match`es (removed from the kept ones), polling up to `timeout` s."""
        deadline = time.monotonic() + timeout
        while True:
            for msg in self.replies:
                if match(msg):
                    self.replies.remove(msg)
                    return msg
            left = deadline - time.monotonic()
            if left <= 0:
                return None
            self.poll(min(left, 0.1))

    # -- requests with replies -----------------------------------------------------------------
    def command_ack(self, command: int, *params: float, timeout: float = 1.5, tries: int = 3) -> int | None:
        """COMMAND_LONG until its COMMAND_ACK arrives; the MAV_RESULT, or None if none came."""
        for _ in range(tries):
            self.command_long(command, *params)
            ack = self.await_reply(lambda m: m.get_type() == "COMMAND_ACK" and m.command == command, timeout)
            if ack is not None:
                return int(ack.result)
        return None

    def read_params(self, names: list[str], timeout: float = 6.0) -> dict[str, float]:
        """PARAM_REQUEST_READ by name, re-asked every second; the values that came within `timeout`
        (an autopilot ignores names it does not have)."""
        found: dict[str, float] = {}
        deadline = time.monotonic() + timeout
        while (missing := [n for n in names if n not in found]) and time.monotonic() < deadline:
            for name in missing:
                self._conn.mav.param_request_read_send(
                    self.state.system, mavlink.MAV_COMP_ID_AUTOPILOT1, name.encode(), -1
                )
            ask_again = min(deadline, time.monotonic() + 1.0)
            while time.monotonic() < ask_again:
                msg = self.await_reply(lambda m: m.get_type() == "PARAM_VALUE" and m.param_id in missing, 0.1)
                if msg is not None:
                    found[msg.param_id] = self._param_value(msg)
                    if all(n in found for n in names):
                        break
        return found

    def set_param(self, name: str, value: float, timeout: float = 1.5, tries: int = 3) -> bool:
        """PARAM_SET (in the parameter's own type, once it has been read) until the PARAM_VALUE echo
        shows `value`."""
        kind = self.param_types.get(name, mavlink.MAV_PARAM_TYPE_REAL32)
        for _ in range(tries):
            self._conn.mav.param_set_send(
                self.state.system,
                mavlink.MAV_COMP_ID_AUTOPILOT1,
                name.encode(),
                self._encode_param(value, kind),
                kind,
            )
            echo = self.await_reply(lambda m: m.get_type() == "PARAM_VALUE" and m.param_id == name, timeout)
            if echo is not None and math.isclose(self._param_value(echo), value, rel_tol=1e-6, abs_tol=1e-6):
                return True
        return False

    def _bytewise(self, kind: int) -> bool:
        """PX4 sends integer parameters byte-wise in PARAM_VALUE's float; ArduPilot casts them."""
        return self.state.px4 and kind in INTEGER_PARAMS

    def _param_value(self, msg: mavlink.MAVLink_message) -> float:
        if self._bytewise(msg.param_type):
            return float(struct.unpack("<i", struct.pack("<f", msg.param_value))[0])
        return float(msg.param_value)

    def _encode_param(self, value: float, kind: int) -> float:
        if self._bytewise(kind):
            return float(struct.unpack("<f", struct.pack("<i", round(value)))[0])
        return value

    # -- guidance ----------------------------------------------------------------------------------
    def command_long(self, command: int, *params: float) -> None:
        p = [*params, *([0.0] * (7 - len(params)))]
        self._conn.mav.command_long_send(self.state.system, mavlink.MAV_COMP_ID_AUTOPILOT1, command, 0, *p)

    def command_int(
        self, command: int, frame: int, params: tuple[float, float, float, float], x: int, y: int, z: float
    ) -> None:
        self._conn.mav.command_int_send(
            self.state.system, mavlink.MAV_COMP_ID_AUTOPILOT1, frame, command, 0, 0, *params, x, y, z
        )

    def turn_rate(self, rate: float) -> None:
        """Body yaw rate (rad/s, MAVLink sign: positive turns clockwise) via SET_ATTITUDE_TARGET."""
        ignore = (
            mavlink.ATTITUDE_TARGET_TYPEMASK_BODY_ROLL_RATE_IGNORE
            | mavlink.ATTITUDE_TARGET_TYPEMASK_BODY_PITCH_RATE_IGNORE
            | mavlink.ATTITUDE_TARGET_TYPEMASK_THROTTLE_IGNORE
            | mavlink.ATTITUDE_TARGET_TYPEMASK_ATTITUDE_IGNORE
        )
        self._conn.mav.set_attitude_target_send(
            0,
            self.state.system,
            mavlink.MAV_COMP_ID_AUTOPILOT1,
            ignore,
            [1.0, 0.0, 0.0, 0.0],
            0.0,
            0.0,
            rate,
            0.0,
        )

    def change_heading(self, yaw_deg: float, accel: float) -> None:
        """MAV_CMD_GUIDED_CHANGE_HEADING: heading type 1 (heading), 0-360 degrees clockwise from north,
        param3 the largest centripetal acceleration (m/s^2) the turn may use (ArduPlane: bank limit
        atan(accel / g); it clamps the value to at least 0.05, so 0 means "do not turn")."""
        self.command_long(mavlink.MAV_CMD_GUIDED_CHANGE_HEADING, 1, yaw_deg % 360.0, accel)

    def change_altitude(self, up: float) -> None:
        """MAV_CMD_GUIDED_CHANGE_ALTITUDE (COMMAND_INT, relative altitude; param3 0: the autopilot's
        own climb rate)."""
        self.command_int(
            mavlink.MAV_CMD_GUIDED_CHANGE_ALTITUDE,
            mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
            (0.0, 0.0, 0.0, 0.0),
            0,
            0,
            up,
        )

    def reposition(self, lat: float, lon: float, up: float) -> None:
        """MAV_CMD_DO_REPOSITION as COMMAND_INT to `up` metres above home. ArduPilot: relative
        altitude, without the change-mode flag (it flies it in GUIDED). PX4: AMSL (it reads the
        altitude as AMSL whatever the frame) with the change-mode flag (without it PX4 answers
        UNSUPPORTED; with it, it switches to Hold)."""
        s = self.state
        if s.px4:
            frame, flags, z = (
                mavlink.MAV_FRAME_GLOBAL_INT,
                mavlink.MAV_DO_REPOSITION_FLAGS_CHANGE_MODE,
                s.home_amsl + up,
            )
        else:
            frame, flags, z = mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, 0, up
        self.command_int(
            mavlink.MAV_CMD_DO_REPOSITION,
            frame,
            (-1.0, float(flags), 0.0, math.nan),
            round(lat * 1e7),
            round(lon * 1e7),
            z,
        )

    def takeoff(self, up: float) -> int | None:
        """MAV_CMD_NAV_TAKEOFF to `up` metres above home (PX4: AMSL in param7; it switches to
        AUTO.TAKEOFF); the MAV_RESULT, or None."""
        return self.command_ack(
            mavlink.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, math.nan, math.nan, self.state.home_amsl + up
        )

    def position_target(self, lat: float, lon: float, up: float) -> None:
        """SET_POSITION_TARGET_GLOBAL_INT, position only, relative altitude (PX4 OFFBOARD)."""
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
        self._conn.mav.set_position_target_global_int_send(
            0,
            self.state.system,
            mavlink.MAV_COMP_ID_AUTOPILOT1,
            mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
            mask,
            round(lat * 1e7),
            round(lon * 1e7),
            up,
            0,
            0,
            0,
            0,
            0,
            0,
            0,
            0,
        )

    def mission_count(self, count: int, mission_type: int) -> None:
        """MISSION_COUNT: starts an upload of `count` items of `mission_type`."""
        self._conn.mav.mission_count_send(
            self.state.system, mavlink.MAV_COMP_ID_AUTOPILOT1, count, mission_type
        )

    def mission_item(
        self,
        seq: int,
        mission_type: int,
        frame: int,
        command: int,
        params: tuple[float, float, float, float],
        x: int,
        y: int,
        z: float,
    ) -> None:
        """MISSION_ITEM_INT `seq` of an upload of `mission_type` (autocontinue on)."""
        self._conn.mav.mission_item_int_send(
            self.state.system,
            mavlink.MAV_COMP_ID_AUTOPILOT1,
            seq,
            frame,
            command,
            0,
            1,
            *params,
            x,
            y,
            z,
            mission_type,
        )

    def change_speed(self, speed: float) -> None:
        """MAV_CMD_DO_CHANGE_SPEED: airspeed (type 0) in m/s, throttle unchanged."""
        self.command_long(mavlink.MAV_CMD_DO_CHANGE_SPEED, 0, speed, -1)

    def set_mode(self, custom_mode: int) -> None:
        """MAV_CMD_DO_SET_MODE with a custom mode (PX4: main and sub mode split into params 2 and 3)."""
        if self.state.px4:
            self.command_long(
                mavlink.MAV_CMD_DO_SET_MODE,
                mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
                (custom_mode >> 16) & 0xFF,
                (custom_mode >> 24) & 0xFF,
            )
        else:
            self.command_long(
                mavlink.MAV_CMD_DO_SET_MODE, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, custom_mode
            )

    def arm(self) -> None:
        self.command_long(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)

    def provision_signing(self, secret: bytes) -> None:
        """SETUP_SIGNING: give the autopilot its signing secret (ArduPilot stores it and from then on
        refuses unsigned commands on every link but its first, the USB one). The secret travels in
        clear: only over a link that cannot be overheard (USB, or SITL on loopback)."""
        autopilot = mavlink.MAV_COMP_ID_AUTOPILOT1
        self._conn.mav.setup_signing_send(self.state.system, autopilot, secret, signing_timestamp())

    @property
    def system_id(self) -> int:
        """The system id this link speaks as."""
        return int(self._conn.mav.srcSystem)

    def close(self) -> None:
        self.refusals.flush()
        with contextlib.suppress(OSError, AttributeError):  # pymavlink's TCP link after a failed reconnect
            self._conn.close()
        if self._tlog:
            self._tlog.close()


def open_link(
    url: str,
    frame: LocalFrame,
    timeout: float,
    should_stop: Callable[[], bool] = lambda: False,
    on_retry: Callable[[LinkNotOpen], None] | None = None,
    **options: Any,
) -> VehicleLink | None:
    """A `VehicleLink(url, frame, **options)`, tried again every `RETRY_OPEN_S` while the link
    cannot be opened (an autopilot's TCP port not listening yet, a serial device not there yet;
    `on_retry` hears the first failure): None if `should_stop` says so first; LinkError naming the
    link and the reason once `timeout` seconds have passed."""
    deadline = time.monotonic() + timeout
    while not should_stop():
        try:
            return VehicleLink(url, frame, **options)
        except LinkNotOpen as exc:
            if time.monotonic() >= deadline:
                raise LinkError(f"cannot open {url} (tried for {timeout:.0f} s): {exc}") from None
            if on_retry is not None:
                on_retry(exc)
                on_retry = None  # the first failure only
            time.sleep(RETRY_OPEN_S)
    return None
