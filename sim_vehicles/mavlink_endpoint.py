"""One vehicle's MAVLink 2 UDP endpoint: a listening socket, its peers, and the codec.

Like ArduPilot SITL's UDP server: every address that sends the vehicle a valid frame becomes a
peer until silent for PEER_TIMEOUT. Each datagram is split into frames on its own; anything
undecodable is counted and skipped. With a signing secret it signs what it sends and accepts only
frames signed with it (docs/simulator.md, "Endpoints").
"""

from __future__ import annotations

import contextlib
import socket
from dataclasses import dataclass

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.contracts.mavlink_signing import keep_stream_timestamps, signing_timestamp

PEER_TIMEOUT = 30.0  # wall seconds without traffic before a peer is forgotten
MAX_PEERS = 16
MAX_DATAGRAMS_PER_READ = 256
_V2, _V1 = 0xFD, 0xFE
UNSIGNED_ALLOWED = frozenset({mavlink.MAVLINK_MSG_ID_RADIO_STATUS, mavlink.MAVLINK_MSG_ID_RADIO})

Address = tuple[str, int]


@dataclass
class InputStats:
    """What a vehicle received: datagrams, good frames, and the three kinds of bad input."""

    datagrams: int = 0
    frames: int = 0
    bad_frames: int = 0  # garbage, truncated, bad CRC, unknown message id
    unhandled: int = 0  # valid messages the vehicle does not act on
    rejected: int = 0  # values out of range, commands denied for their arguments
    unsigned: int = 0  # signing on: frames without a signature
    bad_signature: int = 0  # signing on: wrong key, or a replayed (not newer) timestamp

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

    def __init__(self, host: str, port: int, sysid: int, signing_secret: bytes | None = None) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self.sock.bind((host, port))
        except OSError as exc:  # another simulator of this mission, most likely
            self.sock.close()
            where = f"vehicle {sysid - 1}'s MAVLink endpoint udp {host}:{port}"
            raise OSError(exc.errno, f"{where}: {exc.strerror}") from None
        self.sock.setblocking(False)
        self.mav = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=1)
        self.peers: dict[Address, float] = {}
        self.stats = InputStats()
        if signing_secret is not None:
            signing = self.mav.signing
            signing.secret_key = signing_secret
            signing.sign_outgoing = True
            signing.link_id = 0
            signing.timestamp = signing_timestamp()
            signing.allow_unsigned_callback = lambda _mav, msg_id: msg_id in UNSIGNED_ALLOWED
            keep_stream_timestamps(self.mav)

    @property
    def signing(self) -> bool:
        return self.mav.signing.secret_key is not None

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
                except Exception as exc:  # pymavlink raises MAVError, struct.error, ... on corrupt frames
                    self._count_bad(exc, frame)
                    continue
                if self.signing and not msg.get_signed():
                    if msg.get_msgId() not in UNSIGNED_ALLOWED:  # an unknown id: never checked
                        self.stats.unsigned += 1
                        continue
                    self.stats.frames += 1
                    out.append((msg, addr))  # the radio's status: taken, but its sender gets nothing
                    continue
                self.stats.frames += 1
                out.append((msg, addr))
                self._touch(addr, now)
        return out

    def _signed(self, frame: bytes) -> bool:
        """Whether `frame` is a signed MAVLink2 frame and signing is on."""
        return self.signing and frame[0] == _V2 and bool(frame[2] & 1) and len(frame) >= 25

    def _count_bad(self, exc: Exception, frame: bytes) -> None:
        """Count an undecodable frame: bad, unsigned, or badly signed.

        Count an undecodable frame: bad, unsigned, or badly signed (its stream's timestamp is
        already put back by `keep_stream_timestamps`)."""
        if "signature" not in str(exc):
            self.stats.bad_frames += 1
        elif not self._signed(frame):
            self.stats.unsigned += 1
        else:
            self.stats.bad_signature += 1

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

    def forward(self, frame: bytes | bytearray, addr: Address) -> None:
        """Send another sender's frame on to `addr` as it is (MAVLink routing)."""
        with contextlib.suppress(OSError):
            self.sock.sendto(bytes(frame), addr)

    def close(self) -> None:
        self.sock.close()
