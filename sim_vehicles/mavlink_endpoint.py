"""One vehicle's MAVLink 2 UDP endpoint: a listening socket, its peers, and the codec.

Like ArduPilot SITL's UDP server: the vehicle listens on its port; every address that sends it a
valid MAVLink frame becomes a peer and receives its telemetry until silent for PEER_TIMEOUT.
Each datagram is split into frames independently (a truncated frame never swallows the next
datagram); anything undecodable is counted and skipped.
"""

from __future__ import annotations

import contextlib
import socket
from dataclasses import dataclass

from pymavlink.dialects.v20 import ardupilotmega as mavlink

PEER_TIMEOUT = 30.0  # wall seconds without traffic before a peer is forgotten
MAX_PEERS = 16
MAX_DATAGRAMS_PER_READ = 256
_V2, _V1 = 0xFD, 0xFE

Address = tuple[str, int]


@dataclass
class InputStats:
    """What a vehicle received: datagrams, good frames, and the three kinds of bad input."""

    datagrams: int = 0
    frames: int = 0
    bad_frames: int = 0  # garbage, truncated, bad CRC, unknown message id
    unhandled: int = 0  # valid messages the vehicle does not act on
    rejected: int = 0  # values out of range, commands denied for their arguments

    def add(self, other: InputStats) -> None:
        for name in self.__dataclass_fields__:
            setattr(self, name, getattr(self, name) + getattr(other, name))


def split_frames(data: bytes) -> tuple[list[bytes], int]:
    """The candidate MAVLink frames of one datagram and the number of unframeable chunks."""
    frames: list[bytes] = []
    bad, i, n = 0, 0, len(data)
    while i < n:
        magic = data[i]
        if magic not in (_V2, _V1):
            bad += 1
            i = _next_magic(data, i + 1)
            continue
        if magic == _V2:
            if i + 3 > n:
                return frames, bad + 1
            end = i + 12 + data[i + 1] + (13 if data[i + 2] & 1 else 0)
        else:
            end = i + 8 + data[i + 1] if i + 1 < n else n + 1
        if end > n:
            return frames, bad + 1
        frames.append(data[i:end])
        i = end
    return frames, bad


def _next_magic(data: bytes, start: int) -> int:
    positions = [p for p in (data.find(bytes([_V2]), start), data.find(bytes([_V1]), start)) if p >= 0]
    return min(positions, default=len(data))


class MavlinkEndpoint:
    """UDP socket of one vehicle: receives and decodes, sends to one or all peers."""

    def __init__(self, host: str, port: int, sysid: int) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind((host, port))
        self.sock.setblocking(False)
        self.mav = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=1)
        self.peers: dict[Address, float] = {}
        self.stats = InputStats()

    def fileno(self) -> int:
        return self.sock.fileno()

    def receive(self, now: float) -> list[tuple[mavlink.MAVLink_message, Address]]:
        """Decode every pending datagram; `now` (wall s) marks senders of valid frames as peers."""
        out: list[tuple[mavlink.MAVLink_message, Address]] = []
        for _ in range(MAX_DATAGRAMS_PER_READ):
            try:
                data, addr = self.sock.recvfrom(65535)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:
                continue
            self.stats.datagrams += 1
            frames, bad = split_frames(data)
            self.stats.bad_frames += bad
            for frame in frames:
                try:
                    msg = self.mav.decode(bytearray(frame))
                except Exception:  # pymavlink raises MAVError, struct.error, ... on corrupt frames
                    self.stats.bad_frames += 1
                    continue
                self.stats.frames += 1
                out.append((msg, addr))
                self._touch(addr, now)
        return out

    def _touch(self, addr: Address, now: float) -> None:
        if addr not in self.peers and len(self.peers) >= MAX_PEERS:
            del self.peers[min(self.peers, key=self.peers.__getitem__)]
        self.peers[addr] = now

    def expire(self, now: float) -> None:
        for addr in [a for a, seen in self.peers.items() if now - seen > PEER_TIMEOUT]:
            del self.peers[addr]

    def send(self, msg: mavlink.MAVLink_message, addr: Address | None = None) -> None:
        """Send to `addr`, or to every peer when None."""
        if not self.peers:
            return
        buf = msg.pack(self.mav)
        for a in (addr,) if addr is not None else tuple(self.peers):
            with contextlib.suppress(OSError):  # a vanished peer must not stop the vehicle
                self.sock.sendto(buf, a)

    def close(self) -> None:
        self.sock.close()
