"""Uploading items to the autopilot with the MAVLink mission protocol (missions and fences).

The client sends MISSION_COUNT; the autopilot asks for each item (MISSION_REQUEST_INT, or the older
MISSION_REQUEST) and ends with MISSION_ACK. A lost message is recovered by starting again.
"""

from __future__ import annotations

from dataclasses import dataclass

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.node.vehicle_link import VehicleLink

UPLOAD_TRIES = 3
REPLY_TIMEOUT_S = 2.0


@dataclass(frozen=True)
class Item:
    """One MISSION_ITEM_INT: frame, command, param1-4, x and y (degrees * 1e7), z."""

    frame: int
    command: int
    params: tuple[float, float, float, float]
    x: int = 0
    y: int = 0
    z: float = 0.0


def upload(link: VehicleLink, mission_type: int, items: list[Item], what: str) -> str | None:
    """Upload `items` as the autopilot's list of `mission_type`; the reason on failure.

    `what` names the list in the reason.
    """
    count = len(items)

    def reply(m: mavlink.MAVLink_message) -> bool:
        return (
            m.get_type() in ("MISSION_REQUEST", "MISSION_REQUEST_INT", "MISSION_ACK")
            and m.mission_type == mission_type
        )

    for _ in range(UPLOAD_TRIES):
        link.mission_count(count, mission_type)
        while (msg := link.await_reply(reply, REPLY_TIMEOUT_S)) is not None:
            if msg.get_type() == "MISSION_ACK":
                if msg.type == mavlink.MAV_MISSION_ACCEPTED:
                    return None
                return f"the autopilot refused the {what} (MISSION_ACK {msg.type})"
            if not 0 <= msg.seq < count:
                return f"the autopilot asked for {what} item {msg.seq} of {count}"
            it = items[msg.seq]
            link.mission_item(msg.seq, mission_type, it.frame, it.command, it.params, it.x, it.y, it.z)
    return f"no answer to the {what} upload"
