"""MAVLink 2 signing helpers shared by the companion's vehicle link and the bundled simulator."""

from __future__ import annotations

import time

from pymavlink.dialects.v20 import ardupilotmega as mavlink


def signing_timestamp(now: float | None = None) -> int:
    """A MAVLink signing timestamp: 10 us units since 2015-01-01 UTC."""
    return int(((time.time() if now is None else now) - 1420070400) * 1e5)


def keep_stream_timestamps(mav: mavlink.MAVLink) -> None:
    """Make `mav` put a stream's timestamp back when a frame's signature fails.

    pymavlink sets it before checking, so one forged frame stamped far ahead would lock the genuine
    stream out.
    """
    check = mav.check_signature

    def checked(msgbuf: bytearray, src_system: int, src_component: int) -> bool:
        stream = (msgbuf[-13], src_system, src_component)
        timestamps = mav.signing.stream_timestamps
        before = timestamps.get(stream)
        if check(msgbuf, src_system, src_component):
            return True
        if before is None:
            timestamps.pop(stream, None)
        else:
            timestamps[stream] = before
        return False

    mav.check_signature = checked
