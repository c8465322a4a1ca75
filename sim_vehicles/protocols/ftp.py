"""MAVFTP: the simulator has no file system, so every request is answered with a NAK.

Ground stations (MAVProxy, QGroundControl) try MAVFTP for the parameter file first; a prompt NAK
makes them fall back to PARAM_REQUEST_LIST in about a second instead of timing out.
"""

from __future__ import annotations

OP_NAK = 129
OP_OPEN_FILE_RO = 4
ERR_UNKNOWN_COMMAND = 7
ERR_FILE_NOT_FOUND = 10
HEADER = 12  # seq (2), session, opcode, size, req_opcode, burst_complete, padding, offset (4)


def nak_payload(request: bytes) -> list[int] | None:
    """The 251-byte FILE_TRANSFER_PROTOCOL payload answering `request`, or None if malformed."""
    if len(request) < HEADER:
        return None
    seq = (int.from_bytes(request[0:2], "little") + 1) & 0xFFFF
    opcode = request[3]
    error = ERR_FILE_NOT_FOUND if opcode == OP_OPEN_FILE_RO else ERR_UNKNOWN_COMMAND
    header = seq.to_bytes(2, "little") + bytes([request[2], OP_NAK, 1, opcode, 0, 0]) + bytes(4)
    payload = header + bytes([error])
    return list(payload + bytes(251 - len(payload)))
