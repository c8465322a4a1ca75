"""The vehicle link's MAVLink2 signing: sign what it sends, accept only frames signed alike."""

from __future__ import annotations

from typing import TYPE_CHECKING

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.contracts.mavlink_signing import keep_stream_timestamps, signing_timestamp
from companion.node.link_telemetry import VehicleState

if TYPE_CHECKING:
    from pymavlink import mavutil

UNSIGNED_ALLOWED = frozenset({mavlink.MAVLINK_MSG_ID_RADIO_STATUS, mavlink.MAVLINK_MSG_ID_RADIO})


def frame_sender(data: bytes) -> tuple[str, str]:
    """(kind, sender) of a frame refused for its signature.

    The kind is "bad signature" if it was signed, "unsigned" if not; the sender is
    "system S component C" from its header.
    """
    if len(data) >= 10 and data[0] == 0xFD:
        kind = "bad signature" if data[2] & 1 else "unsigned"
        return kind, f"system {data[5]} component {data[6]}"
    if len(data) >= 6 and data[0] == 0xFE:
        return "unsigned", f"system {data[3]} component {data[4]}"
    return "unsigned", "unknown"


class Signing:
    """One link's signing (`link.signing`), as between ArduPilot and a ground station.

    Once signing is set up, the radio's RADIO_STATUS is the only unsigned frame accepted
    (docs/companion.md).
    """

    def __init__(self, conn: mavutil.mavfile, state: VehicleState, secret: bytes | None) -> None:
        """With a `secret`, sign every frame sent and refuse frames not signed with it.

        A frame whose signature fails never moves its stream's timestamp (`keep_stream_timestamps`).
        """
        self._conn, self._state = conn, state
        if secret is not None:
            conn.setup_signing(
                secret,
                sign_outgoing=True,
                allow_unsigned_callback=lambda _mav, msg_id: msg_id in UNSIGNED_ALLOWED,
                link_id=0,
            )
            keep_stream_timestamps(conn.mav)

    @property
    def enabled(self) -> bool:
        """True when the link signs what it sends and accepts only signed frames."""
        return self._conn.mav.signing.secret_key is not None

    def provision(self, secret: bytes) -> None:
        """SETUP_SIGNING: give the autopilot its signing secret.

        ArduPilot stores it and from then on refuses unsigned commands on every link but its first,
        the USB one. The secret travels in clear: only over a link that cannot be overheard (USB, or
        SITL on loopback).
        """
        autopilot = mavlink.MAV_COMP_ID_AUTOPILOT1
        self._conn.mav.setup_signing_send(self._state.system, autopilot, secret, signing_timestamp())
