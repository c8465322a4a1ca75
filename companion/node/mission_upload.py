"""The vehicle link's mission protocol: uploading items to the autopilot and reading them back.

Upload: the client sends MISSION_COUNT; the autopilot asks for each item (MISSION_REQUEST_INT, or
the older MISSION_REQUEST) and ends with MISSION_ACK. Download: the client sends
MISSION_REQUEST_LIST, the autopilot answers MISSION_COUNT, the client asks for each item
(MISSION_REQUEST_INT) and ends with MISSION_ACK. A lost message is recovered by asking again.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

from pymavlink.dialects.v20 import ardupilotmega as mavlink

if TYPE_CHECKING:
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


class MissionUpload:
    """The mission protocol over one link (`link.mission`)."""

    def __init__(self, link: VehicleLink) -> None:
        self.link = link

    def upload(self, mission_type: int, items: list[Item], what: str) -> str | None:
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
            self._count(count, mission_type)
            while (msg := self.link.await_reply(reply, REPLY_TIMEOUT_S)) is not None:
                if msg.get_type() == "MISSION_ACK":
                    if msg.type == mavlink.MAV_MISSION_ACCEPTED:
                        return None
                    return f"the autopilot refused the {what} (MISSION_ACK {msg.type})"
                if not 0 <= msg.seq < count:
                    return f"the autopilot asked for {what} item {msg.seq} of {count}"
                self._item(msg.seq, mission_type, items[msg.seq])
        return f"no answer to the {what} upload"

    def download(self, mission_type: int, what: str) -> tuple[list[Item], str | None]:
        """The autopilot's list of `mission_type`, and None; or what it gave and the reason on failure.

        `what` names the list in the reason.
        """
        count = self._list_count(mission_type)
        if count is None:
            return [], f"no answer to the {what} download"
        got: list[Item] = []
        system, autopilot = self.link.state.system, mavlink.MAV_COMP_ID_AUTOPILOT1
        for seq in range(count):
            msg = None
            for _ in range(UPLOAD_TRIES):
                self.link.mav.mission_request_int_send(system, autopilot, seq, mission_type)
                msg = self.link.await_reply(_item_of(mission_type, seq), REPLY_TIMEOUT_S)
                if msg is not None:
                    break
            if msg is None:
                return got, f"no answer for {what} item {seq} of {count}"
            params = (msg.param1, msg.param2, msg.param3, msg.param4)
            got.append(Item(msg.frame, msg.command, params, msg.x, msg.y, msg.z))
        self.link.mav.mission_ack_send(system, autopilot, mavlink.MAV_MISSION_ACCEPTED, mission_type)
        return got, None

    def _list_count(self, mission_type: int) -> int | None:
        """MISSION_REQUEST_LIST until the autopilot's MISSION_COUNT comes; its count, or None."""
        system, autopilot = self.link.state.system, mavlink.MAV_COMP_ID_AUTOPILOT1
        for _ in range(UPLOAD_TRIES):
            self.link.mav.mission_request_list_send(system, autopilot, mission_type)
            msg = self.link.await_reply(
                lambda m: m.get_type() == "MISSION_COUNT" and m.mission_type == mission_type, REPLY_TIMEOUT_S
            )
            if msg is not None:
                return int(msg.count)
        return None

    def _count(self, count: int, mission_type: int) -> None:
        """MISSION_COUNT: starts an upload of `count` items of `mission_type`."""
        self.link.mav.mission_count_send(
            self.link.state.system, mavlink.MAV_COMP_ID_AUTOPILOT1, count, mission_type
        )

    def _item(self, seq: int, mission_type: int, it: Item) -> None:
        """MISSION_ITEM_INT `seq` of an upload of `mission_type` (autocontinue on)."""
        system, autopilot = self.link.state.system, mavlink.MAV_COMP_ID_AUTOPILOT1
        self.link.mav.mission_item_int_send(
            system, autopilot, seq, it.frame, it.command, 0, 1, *it.params, it.x, it.y, it.z, mission_type
        )


def _item_of(mission_type: int, seq: int) -> Callable[[mavlink.MAVLink_message], bool]:
    """Whether a reply is item `seq` of a download of `mission_type`."""
    return lambda m: m.get_type() == "MISSION_ITEM_INT" and m.seq == seq and m.mission_type == mission_type
