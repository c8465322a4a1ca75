"""The companion's MAVLink link to its autopilot: telemetry in, guidance out (pymavlink).

One object, one module per capability (as MAVSDK): the link itself (connection, HEARTBEATs, reading
messages into `state`, `link_telemetry`), `params` (`link_params`), `commands` (`link_commands`),
`mission` (`mission_upload`) and `signing` (`link_signing`). Any pymavlink connection string works;
a .tlog records everything received and sent. It never changes the vehicle's mode or arms it unless
asked to (`companion.node.takeover`). What the link hides of PX4, signing and the frames it refuses:
docs/companion.md, "The vehicle link".
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
from pathlib import Path
from typing import Any, BinaryIO

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.contracts.frames import LocalFrame
from companion.node.link_commands import Commands
from companion.node.link_params import Parameters
from companion.node.link_signing import UNSIGNED_ALLOWED, Signing, frame_sender
from companion.node.link_telemetry import STREAMS_HZ, VehicleState
from companion.node.mission_upload import MissionUpload
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
REPLIES = frozenset({
    "COMMAND_ACK", "PARAM_VALUE", "MISSION_REQUEST", "MISSION_REQUEST_INT", "MISSION_ACK", "MISSION_COUNT",
    "MISSION_ITEM_INT",
})  # fmt: skip


def _loopback(host: str) -> bool:
    try:
        return ipaddress.ip_address(socket.gethostbyname(host)).is_loopback
    except (OSError, ValueError):
        return False


class LinkError(RuntimeError):
    """The vehicle could not be reached."""


class LinkNotOpen(LinkError):
    """The link could not be opened (yet): the reason."""


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
    """One autopilot over MAVLink: its state and its capabilities.

    The capabilities are `params`, `commands`, `mission` and `signing`.
    """

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
        """Open the link to the autopilot at `url` (LinkNotOpen if it cannot be opened).

        `system`: the link's own system id (None: the vehicle's, once its HEARTBEAT is heard);
        `heartbeat`: `poll` sends our HEARTBEAT whenever one is due; `signing_secret`: the link signs
        and accepts only signed frames.
        """
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
        self.system_status = mavlink.MAV_STATE_ACTIVE  # our HEARTBEAT's (`ground_station` sets it)
        # Called after every poll, also while a request waits for its reply: what must go on
        # meanwhile (a setpoint stream that PX4 OFFBOARD must not lose).
        self.on_poll: Callable[[], None] | None = None
        self._conn = self._connect(url, system, component, tlog)
        self.params = Parameters(self)
        self.commands = Commands(self)
        self.mission = MissionUpload(self)
        self.signing = Signing(self._conn, self.state, signing_secret)

    def _connect(self, url: str, system: int | None, component: int, tlog: Path | None) -> mavutil.mavfile:
        """The pymavlink connection, bound to loopback for a loopback udpout, its .tlog attached."""
        try:
            conn = mavutil.mavlink_connection(
                url,
                source_system=255 if system is None else system,
                source_component=component,
                autoreconnect=True,
                dialect="ardupilotmega",
            )
        except OSError as exc:  # a TCP port that refuses, no such serial device
            raise LinkNotOpen(str(exc)) from None
        try:
            self._bind_loopback(conn)
            self._tlog = TlogWriter(tlog) if tlog else None
        except OSError:
            conn.close()
            raise
        if self._tlog:
            tlog_writer = self._tlog
            conn.mav.set_send_callback(lambda m: tlog_writer.write(m.get_msgbuf()))
        return conn

    @staticmethod
    def _bind_loopback(conn: mavutil.mavfile) -> None:
        """A udpout link to a loopback address: bind its socket to loopback before it sends.

        Otherwise the OS would bind it to every interface, where anyone on the network could write
        to it.
        """
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
    def mav(self) -> mavlink.MAVLink:
        """pymavlink's encoder: what the capabilities send with."""
        return self._conn.mav

    @property
    def system_id(self) -> int:
        """The system id this link speaks as."""
        return int(self._conn.mav.srcSystem)

    # -- connection --------------------------------------------------------------------------------
    def wait_heartbeat(self, timeout: float, should_stop: Callable[[], bool] = lambda: False) -> bool:
        """Block until the autopilot's HEARTBEAT arrives: True; False if `should_stop` says so first.

        It sends ours meanwhile, so that udpout links open. LinkError if `timeout` seconds pass
        first.
        """
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
            mavlink.MAV_TYPE_ONBOARD_CONTROLLER, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, self.system_status
        )
        self._beat_wall, self._beat_vehicle = time.monotonic(), self.state.time_s

    def _beat_if_due(self) -> None:
        """Send our HEARTBEAT when one is due in wall time or in vehicle time.

        So the autopilot hears it in every phase of the flight, whatever the simulator's speed-up.
        """
        wall_due = time.monotonic() - self._beat_wall >= HEARTBEAT_WALL_S
        vehicle_due = self.state.time_s - self._beat_vehicle >= HEARTBEAT_VEHICLE_S
        if wall_due or vehicle_due:
            with contextlib.suppress(OSError):  # a TCP vehicle gone: the next poll says so
                self.send_heartbeat()

    def link_alive(self, now: float, timeout: float) -> bool:
        return now - self.state.last_heartbeat <= timeout

    # -- reading -----------------------------------------------------------------------------------
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
        """One message: refused (bad signature, bad data, another system), telemetry, or a reply."""
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
            # not refused: the radio's own status, and the HEARTBEATs an autopilot routes from the
            # other systems on its links (a ground station's), as ArduPilot forwards them to all
            if msg.get_msgId() not in UNSIGNED_ALLOWED and kind != "HEARTBEAT":
                self.wrong_system += 1
                self.refusals.refuse("wrong system", f"system {source[0]} component {source[1]}", kind)
            return
        if not s.update(msg, self.frame) and kind in REPLIES:
            if kind == "PARAM_VALUE":
                self.params.note(msg)
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

    # -- sending -----------------------------------------------------------------------------------
    def command_long(self, command: int, *params: float) -> None:
        """COMMAND_LONG to the autopilot (missing params 0)."""
        p = [*params, *([0.0] * (7 - len(params)))]
        self._conn.mav.command_long_send(self.state.system, mavlink.MAV_COMP_ID_AUTOPILOT1, command, 0, *p)

    def command_int(
        self, command: int, frame: int, params: tuple[float, float, float, float], x: int, y: int, z: float
    ) -> None:
        """COMMAND_INT to the autopilot."""
        self._conn.mav.command_int_send(
            self.state.system, mavlink.MAV_COMP_ID_AUTOPILOT1, frame, command, 0, 0, *params, x, y, z
        )

    def command_ack(self, command: int, *params: float, timeout: float = 1.5, tries: int = 3) -> int | None:
        """COMMAND_LONG until its COMMAND_ACK arrives; the MAV_RESULT, or None if none came."""
        for _ in range(tries):
            self.command_long(command, *params)
            ack = self.await_reply(lambda m: m.get_type() == "COMMAND_ACK" and m.command == command, timeout)
            if ack is not None:
                return int(ack.result)
        return None

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
    """A `VehicleLink(url, frame, **options)`, tried again every `RETRY_OPEN_S` until it opens.

    It is tried again while the link cannot be opened (an autopilot's TCP port not listening yet, a
    serial device not there yet; `on_retry` hears the first failure). None if `should_stop` says so
    first; LinkError naming the link and the reason once `timeout` seconds have passed.
    """
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
