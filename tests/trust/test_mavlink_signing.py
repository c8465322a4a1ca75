"""MAVLink2 signing on the companion-autopilot link, against the real simulator over UDP.

With the mission's keys the simulator behaves like ArduPilot once signing is set up: it answers
only frames signed with the vehicle's secret and newer than the last of their stream; unsigned,
wrongly signed and replayed frames are counted (its exit stats) and get no answer. The companion's
`VehicleLink` signs with the vehicle's secret, and refuses a vehicle that signs with another
(the vehicle signs its telemetry).
Without keys the same unsigned command is answered.
"""

from __future__ import annotations

import os
import secrets
import socket
import time
from collections.abc import Callable
from pathlib import Path

import pytest

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil

from companion.contracts import keys
from companion.contracts.frames import LocalFrame
from companion.core.feasibility import load_mission
from companion.node.vehicle_link import LinkError, VehicleLink
from tests.sim.conftest import SimProcess, write_mission

pytestmark = pytest.mark.timeout(240)
M = mavutil.mavlink
TRIES = 4
QUIET_S = 2.0  # how long a sender that must get no answer listens


def _client(port: int, secret: bytes | None = None) -> mavutil.mavfile:
    conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=250, dialect="ardupilotmega")
    if secret is not None:
        conn.setup_signing(secret, sign_outgoing=True, link_id=1)
    return conn


def _ask(conn: mavutil.mavfile, timeout: float) -> mavutil.mavlink.MAVLink_message | None:
    """One COMMAND_LONG (SET_MESSAGE_INTERVAL, harmless) and its COMMAND_ACK, if one comes."""
    interval = (M.MAVLINK_MSG_ID_SYSTEM_TIME, 1e6, 0, 0, 0, 0, 0)
    conn.mav.command_long_send(1, 1, M.MAV_CMD_SET_MESSAGE_INTERVAL, 0, *interval)
    return conn.recv_match(type="COMMAND_ACK", blocking=True, timeout=timeout)


def test_signing_on_only_signed_commands_are_answered(
    tmp_path: Path, start_sim: Callable[..., SimProcess]
) -> None:
    path, ports, _ = write_mission(tmp_path, n=1)
    keys.generate(tmp_path / "keys", 1)
    path.write_text(path.read_text() + f'\n[security]\nkeys = "{tmp_path / "keys"}"\n')
    secret = keys.mavlink_secret(tmp_path / "keys" / "uav-0" / "mavlink.key")
    sim = start_sim(path)
    assert any("requires MAVLink2-signed input" in line for line in sim.lines)

    unsigned, wrong = _client(ports[0]), _client(ports[0], secrets.token_bytes(32))
    for _ in range(TRIES):
        assert _ask(unsigned, 0.1) is None and _ask(wrong, 0.1) is None
    good = _client(ports[0], secret)
    sent: list[bytes] = []
    good.mav.set_send_callback(lambda m: sent.append(bytes(m.get_msgbuf())))
    ack = _ask(good, 20.0)
    assert ack is not None and ack.get_signed(), "the vehicle answers a signed command, signed"
    frame = sent[-1]
    far_future = frame[:-12] + b"\xff" * 6 + frame[-6:]  # a forged timestamp: the signature fails
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as replayer:
        replayer.sendto(frame, ("127.0.0.1", ports[0]))  # the same signed frame again
        replayer.sendto(far_future, ("127.0.0.1", ports[0]))
    assert _ask(good, 20.0) is not None, "a forged frame must not lock the genuine sender out"
    assert unsigned.recv_match(type="COMMAND_ACK", blocking=True, timeout=QUIET_S) is None
    assert wrong.recv_match(type="COMMAND_ACK", blocking=True, timeout=0.1) is None

    # the companion's link: with the vehicle's secret it connects, with another it refuses
    local = LocalFrame(load_mission(path).region.origin)
    link = VehicleLink(f"udpout:127.0.0.1:{ports[0]}", local, signing_secret=secret)
    link.wait_heartbeat(30.0)
    assert link.signing.enabled and link.unauthenticated == 0
    link.close()
    stranger = VehicleLink(f"udpout:127.0.0.1:{ports[0]}", local, signing_secret=secrets.token_bytes(32))
    with pytest.raises(LinkError):
        stranger.wait_heartbeat(3.0)
    stranger.close()
    rc, stats = sim.stop()
    assert rc == 0
    assert stats["input"]["unsigned"] == TRIES, stats  # one COMMAND_LONG per try
    # the wrong key's commands, the replay, the forgery, and the stranger's heartbeats
    assert stats["input"]["bad_signature"] >= TRIES + 2 + 1, stats
    for conn in (unsigned, wrong, good):
        conn.close()


def test_signing_off_the_same_unsigned_command_is_answered(
    tmp_path: Path, start_sim: Callable[..., SimProcess]
) -> None:
    path, ports, _ = write_mission(tmp_path, n=1)
    sim = start_sim(path)
    assert any("UNSIGNED: accepts any sender" in line for line in sim.lines)
    conn = _client(ports[0])
    deadline = time.monotonic() + 30.0
    ack = None
    while ack is None and time.monotonic() < deadline:
        ack = _ask(conn, 1.0)
    assert ack is not None and not ack.get_signed()
    rc, stats = sim.stop()
    assert rc == 0 and stats["input"]["unsigned"] == stats["input"]["bad_signature"] == 0
    conn.close()


def test_signing_on_an_unknown_message_id_earns_no_telemetry(
    tmp_path: Path, start_sim: Callable[..., SimProcess]
) -> None:
    """pymavlink decodes a frame of an unknown message id before it looks at the signature: such a
    frame, unsigned, must not make its sender a peer (it used to receive the vehicle's telemetry)."""
    path, ports, _ = write_mission(tmp_path, n=1)
    keys.generate(tmp_path / "keys", 1)
    path.write_text(path.read_text() + f'\n[security]\nkeys = "{tmp_path / "keys"}"\n')
    sim = start_sim(path)
    payload = b"\x00" * 4
    unknown = bytes([0xFD, len(payload), 0, 0, 0, 250, 1, 0xEF, 0xBE, 0x00]) + payload + b"\x00\x00"
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        s.settimeout(0.2)
        heard = 0
        deadline = time.monotonic() + 3 * QUIET_S
        while time.monotonic() < deadline:
            s.sendto(unknown, ("127.0.0.1", ports[0]))
            try:
                s.recvfrom(65535)
                heard += 1
            except TimeoutError:
                pass
    rc, stats = sim.stop()
    assert rc == 0
    assert heard == 0, f"{heard} datagrams sent to an unauthenticated sender"
    assert stats["input"]["unsigned"] > 0, stats
