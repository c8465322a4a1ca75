"""The companion's HEARTBEAT keeps going while its link drains a backlog of telemetry.

A loaded machine or a sped-up vehicle (ArduPlane SITL at 8x) can leave seconds of vehicle time
queued on the link; before this was fixed `poll` sent no HEARTBEAT until the queue was empty, and
ArduPlane's GCS failsafe (which watches the companion's HEARTBEAT in vehicle time) fired while the
companion lived (CI: 3.6 s of silence at 8x, the failsafe 6.4 s after the companion's last poll
instead of 10). Real UDP on loopback: a scripted vehicle queues 96 s of positions in three
datagrams, and one `poll` must answer them with a HEARTBEAT every 0.5 s of vehicle time.
"""

from __future__ import annotations

import socket

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.contracts.frames import LocalFrame
from companion.contracts.mission import Origin
from companion.node.vehicle_link import HEARTBEAT_VEHICLE_S, VehicleLink

COMPANION = 200
STEP_MS = 20
PER_DATAGRAM = 1600  # 1,600 GLOBAL_POSITION_INT frames of 40 bytes: one UDP datagram under 64 KiB
DATAGRAMS = 3


class _Buffer:
    def __init__(self) -> None:
        self.data = bytearray()

    def write(self, b: bytes) -> None:
        self.data += b


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _companion_heartbeats(vehicle: socket.socket) -> int:
    """HEARTBEATs from the companion's system id waiting on the vehicle's socket."""
    parser = mavlink.MAVLink(None)
    count = 0
    while True:
        try:
            datagram = vehicle.recv(65536)
        except BlockingIOError:
            return count
        for msg in parser.parse_buffer(datagram) or []:
            count += msg.get_type() == "HEARTBEAT" and msg.get_srcSystem() == COMPANION


def test_a_long_backlog_does_not_silence_the_companion() -> None:
    port = _free_port()
    link = VehicleLink(
        f"udpin:127.0.0.1:{port}",
        LocalFrame(Origin(lat=-35.0, lon=149.0, alt=0.0)),
        system=COMPANION,
        heartbeat=True,
    )
    vehicle = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        vehicle.bind(("127.0.0.1", 0))
        out = _Buffer()
        autopilot = mavlink.MAVLink(out, srcSystem=1, srcComponent=mavlink.MAV_COMP_ID_AUTOPILOT1)

        def send() -> None:
            vehicle.sendto(bytes(out.data), ("127.0.0.1", port))
            out.data.clear()

        autopilot.heartbeat_send(mavlink.MAV_TYPE_FIXED_WING, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 0)
        send()
        link.wait_heartbeat(30)
        assert link.state.system == 1
        vehicle.setblocking(False)
        _companion_heartbeats(vehicle)  # those sent while connecting

        t_ms = 1000
        for _ in range(DATAGRAMS):
            for _ in range(PER_DATAGRAM):
                autopilot.global_position_int_send(
                    t_ms, -350000000, 1490000000, 100000, 100000, 2000, 0, 0, 0
                )
                t_ms += STEP_MS
            send()
        link.poll(5.0)  # the whole backlog, in one poll
        queued_s = DATAGRAMS * PER_DATAGRAM * STEP_MS * 1e-3
        assert link.state.time_s > 1.0 + 0.99 * queued_s - 1.0, link.state.time_s  # every datagram read
        beats = _companion_heartbeats(vehicle)
        assert beats >= 0.8 * queued_s / HEARTBEAT_VEHICLE_S, (
            f"{beats} HEARTBEATs over {queued_s:.0f} s of vehicle time"
        )
    finally:
        vehicle.close()
        link.close()
