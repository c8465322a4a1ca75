"""A vehicle link that cannot be opened yet (an autopilot's TCP port not listening, a serial device
not there) is tried again until the vehicle wait runs out (`vehicle_link.open_link`), then is an
error naming the link and the reason, never a traceback. Real TCP on loopback."""

from __future__ import annotations

import socket
import threading

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.contracts.frames import LocalFrame
from companion.contracts.mission import Origin
from companion.node.vehicle_link import LinkError, LinkNotOpen, open_link

FRAME = LocalFrame(Origin(lat=47.0, lon=8.0, alt=500.0))
WAIT_S = 60.0  # generous: the test never waits for it, events drive it


def _unused_tcp_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _heartbeat() -> bytes:
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    msg = mav.heartbeat_encode(mavlink.MAV_TYPE_FIXED_WING, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 0)
    return msg.pack(mav)


def test_a_tcp_autopilot_that_starts_listening_later_is_reached() -> None:
    port = _unused_tcp_port()
    refused, served = threading.Event(), threading.Event()
    errors: list[LinkNotOpen] = []

    def autopilot() -> None:  # listens only once the companion has been refused
        refused.wait(WAIT_S)
        with socket.socket() as server:
            server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            server.bind(("127.0.0.1", port))
            server.listen(1)
            server.settimeout(WAIT_S)
            conn, _ = server.accept()
            with conn:
                for _ in range(int(WAIT_S * 10)):
                    conn.sendall(_heartbeat())
                    if served.wait(0.1):
                        break

    thread = threading.Thread(target=autopilot, daemon=True)
    thread.start()

    def retrying(exc: LinkNotOpen) -> None:
        errors.append(exc)
        refused.set()

    link = open_link(f"tcp:127.0.0.1:{port}", FRAME, WAIT_S, on_retry=retrying)
    try:
        assert link is not None
        assert len(errors) == 1 and "Connection refused" in str(errors[0]), errors
        assert link.wait_heartbeat(WAIT_S)
        assert link.state.system == 1
    finally:
        served.set()
        if link is not None:
            link.close()
        thread.join(WAIT_S)


def test_a_link_that_cannot_be_opened_is_an_error_naming_it(tmp_path) -> None:
    device = tmp_path / "ttyACM9"  # no such serial device
    with pytest.raises(LinkError) as err:
        open_link(str(device), FRAME, 0.0)
    assert str(device) in str(err.value) and "No such file or directory" in str(err.value)


def test_stopped_while_it_retries_it_returns_none() -> None:
    tries: list[LinkNotOpen] = []
    url = f"tcp:127.0.0.1:{_unused_tcp_port()}"
    assert open_link(url, FRAME, WAIT_S, lambda: bool(tries), tries.append) is None
    assert len(tries) == 1
