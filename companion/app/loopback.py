"""Free ports on 127.0.0.1 for the harnesses that start real processes on loopback."""

from __future__ import annotations

import socket


def free_ports(kind: int, n: int) -> list[int]:
    """`n` ports of socket type `kind` (SOCK_DGRAM, SOCK_STREAM) free on 127.0.0.1 right now."""
    socks = [socket.socket(socket.AF_INET, kind) for _ in range(n)]
    try:
        for s in socks:
            s.bind(("127.0.0.1", 0))
        return [s.getsockname()[1] for s in socks]
    finally:
        for s in socks:
            s.close()
