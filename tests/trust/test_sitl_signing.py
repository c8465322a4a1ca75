"""MAVLink2 signing against the real ArduPlane (SITL), as `uavsearch run --autopilot ardupilot-sitl`
sets it up: the camera's link on SERIAL0 (SITL's USB port) gives the autopilot its secret with
SETUP_SIGNING; from then on the companion's signed link on SERIAL1 is answered, and unsigned or
wrongly signed commands on SERIAL2 are not. (ArduPilot keeps answering unsigned frames on its USB
port, so that a ground station can always set signing up there.)
"""

from __future__ import annotations

import os
import secrets
import time
from pathlib import Path

import pytest

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil

from companion.contracts.frames import LocalFrame
from companion.node.vehicle_link import VehicleLink, open_link
from tests.sitl.conftest import GCS_COMPONENT, start_sitl, write_mission

pytestmark = pytest.mark.timeout(300)
M = mavutil.mavlink
QUIET_S = 3.0


def _interval_ack(conn: mavutil.mavfile, timeout: float) -> object | None:
    """SET_MESSAGE_INTERVAL (harmless) and its COMMAND_ACK, if one comes within `timeout` s."""
    interval = (M.MAVLINK_MSG_ID_SYSTEM_TIME, 1e6, 0, 0, 0, 0, 0)
    conn.mav.command_long_send(1, 1, M.MAV_CMD_SET_MESSAGE_INTERVAL, 0, *interval)
    deadline = time.monotonic() + timeout
    while (left := deadline - time.monotonic()) > 0:
        ack = conn.recv_match(type="COMMAND_ACK", blocking=True, timeout=min(left, 0.5))
        if ack is not None and ack.command == M.MAV_CMD_SET_MESSAGE_INTERVAL:
            return ack
    return None


def _connect(url: str, frame: LocalFrame, secret: bytes | None = None) -> VehicleLink:
    link = open_link(url, frame, 60, component=GCS_COMPONENT, signing_secret=secret)
    assert link is not None
    link.wait_heartbeat(60)
    return link


def test_arduplane_sitl_answers_only_signed_commands_once_signing_is_set_up(
    sitl_binary: Path, tmp_path: Path
) -> None:
    mission = write_mission(tmp_path, 1)
    ports = mission.ports(0)
    frame = LocalFrame(mission.mission.region.origin)
    proc = start_sitl(sitl_binary, mission, 0, 1.0, tmp_path)
    links: list[VehicleLink] = []
    try:
        usb = _connect(ports.url(ports.serial0), frame)
        links.append(usb)
        secret = secrets.token_bytes(32)
        usb.signing.provision(secret)
        signed = _connect(ports.url(ports.serial1), frame, secret)
        links.append(signed)
        assert signed.command_ack(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_SYSTEM_TIME, 1e6) == 0
        assert signed.unauthenticated == 0
        other = mavutil.mavlink_connection(ports.url(ports.serial2), source_system=254, source_component=191)
        try:
            assert other.wait_heartbeat(timeout=30) is not None
            assert _interval_ack(other, QUIET_S) is None, "an unsigned command was answered"
            other.setup_signing(secrets.token_bytes(32), sign_outgoing=True, link_id=2)
            assert _interval_ack(other, QUIET_S) is None, "a wrongly signed command was answered"
            other.setup_signing(secret, sign_outgoing=True, link_id=2)
            assert _interval_ack(other, 20.0) is not None, "the right key is answered on any link"
        finally:
            other.close()
    finally:
        for link in links:
            link.close()
        proc.stop()
