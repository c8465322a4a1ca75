"""Free ports on 127.0.0.1 for the harnesses that start real processes on loopback.

Ports are drawn below the kernel's ephemeral range: a port of that range that is free now may be
handed to another process's outgoing socket (a Zenoh client, a pip download, a ground station)
before the process meant to bind it starts (seen on a busy machine: "Address already in use", and
an ArduPlane SITL that accepted its TCP client and then never spoke).
"""

from __future__ import annotations

import os
import socket
import uuid
from pathlib import Path

LOWEST = 20000  # below: well-known services and other software's fixed ports
KINDS = (socket.SOCK_STREAM, socket.SOCK_DGRAM)


def ephemeral_low() -> int:
    """The lowest port the kernel hands out to binds of port 0 and to outgoing sockets."""
    try:
        return int(Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return 32768


def _free(port: int) -> bool:
    """`port` binds on 127.0.0.1 for both TCP and UDP right now."""
    for kind in KINDS:
        with socket.socket(socket.AF_INET, kind) as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                return False
    return True


def free_blocks(n: int, width: int = 1, spacing: int = 10) -> list[int]:
    """`n` base ports P, multiples of `spacing`, each with P..P+width-1 free on 127.0.0.1.

    Free for TCP and UDP, below the ephemeral range where it leaves room (else above 30000); the
    search starts at a random point, so parallel test workers rarely try the same blocks.
    """
    low = ephemeral_low()
    first, last = (LOWEST, low - width) if low - LOWEST >= 2000 else (30000, 65535 - width)
    span = (last - first) // spacing
    start = first + (os.getpid() * 7919 + uuid.uuid4().int) % span * spacing
    bases: list[int] = []
    for base in [*range(start, last, spacing), *range(first, start, spacing)]:
        if all(_free(p) for p in range(base, base + width)):
            bases.append(base)
            if len(bases) == n:
                return bases
    raise OSError(f"no {n} free blocks of {width} loopback ports")


def free_ports(n: int) -> list[int]:
    """`n` ports free on 127.0.0.1 for TCP and UDP right now."""
    return free_blocks(n, width=1, spacing=1)
