"""The vehicle link's parameters: read and set by name, in each parameter's own type."""

from __future__ import annotations

import math
import struct
import time
from typing import TYPE_CHECKING

from pymavlink.dialects.v20 import ardupilotmega as mavlink

if TYPE_CHECKING:
    from companion.node.vehicle_link import VehicleLink

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


class Parameters:
    """The autopilot's parameters over one link (`link.params`).

    PX4 sends integer parameters byte-wise in PARAM_VALUE's float, ArduPilot casts them: both read
    back as their values.
    """

    def __init__(self, link: VehicleLink) -> None:
        self.link = link
        self.types: dict[str, int] = {}  # MAV_PARAM_TYPE of every parameter seen

    def note(self, msg: mavlink.MAVLink_message) -> None:
        """A PARAM_VALUE arrived: keep its parameter's type (for setting it later)."""
        self.types[msg.param_id] = msg.param_type

    def read(self, names: list[str], timeout: float = 6.0) -> dict[str, float]:
        """PARAM_REQUEST_READ by name, re-asked every second; the values that came within `timeout`.

        An autopilot ignores names it does not have.
        """
        link = self.link
        found: dict[str, float] = {}
        deadline = time.monotonic() + timeout
        while (missing := [n for n in names if n not in found]) and time.monotonic() < deadline:
            for name in missing:
                link.mav.param_request_read_send(
                    link.state.system, mavlink.MAV_COMP_ID_AUTOPILOT1, name.encode(), -1
                )
            ask_again = min(deadline, time.monotonic() + 1.0)
            while time.monotonic() < ask_again:
                msg = link.await_reply(lambda m: m.get_type() == "PARAM_VALUE" and m.param_id in missing, 0.1)
                if msg is not None:
                    found[msg.param_id] = self._value(msg)
                    if all(n in found for n in names):
                        break
        return found

    def set(self, name: str, value: float, timeout: float = 1.5, tries: int = 3) -> bool:
        """PARAM_SET until the PARAM_VALUE echo shows `value`; whether it did.

        The value goes in the parameter's own type once it has been read.
        """
        link = self.link
        kind = self.types.get(name, mavlink.MAV_PARAM_TYPE_REAL32)
        for _ in range(tries):
            link.mav.param_set_send(
                link.state.system,
                mavlink.MAV_COMP_ID_AUTOPILOT1,
                name.encode(),
                self._encode(value, kind),
                kind,
            )
            echo = link.await_reply(lambda m: m.get_type() == "PARAM_VALUE" and m.param_id == name, timeout)
            if echo is not None and math.isclose(self._value(echo), value, rel_tol=1e-6, abs_tol=1e-6):
                return True
        return False

    def _bytewise(self, kind: int) -> bool:
        """PX4 sends integer parameters byte-wise in PARAM_VALUE's float; ArduPilot casts them."""
        return self.link.state.px4 and kind in INTEGER_PARAMS

    def _value(self, msg: mavlink.MAVLink_message) -> float:
        if self._bytewise(msg.param_type):
            return float(struct.unpack("<i", struct.pack("<f", msg.param_value))[0])
        return float(msg.param_value)

    def _encode(self, value: float, kind: int) -> float:
        if self._bytewise(kind):
            return float(struct.unpack("<f", struct.pack("<i", round(value)))[0])
        return value
