"""Fixtures for whole-swarm runs."""

from __future__ import annotations

import socket
from pathlib import Path

import pytest


def _free(port: int) -> bool:
    for kind in (socket.SOCK_DGRAM, socket.SOCK_STREAM):
        with socket.socket(socket.AF_INET, kind) as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                return False
    return True


def _ephemeral_low() -> int:
    """The lowest port the kernel hands out to binds of port 0 (other tests' sockets)."""
    try:
        return int(Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return 32768


@pytest.fixture
def free_base_port() -> int:
    """A base port p with p + 10 i (vehicles) and p + 7, p + 8 (mesh) free on 127.0.0.1, below the
    ephemeral range where it can be: a free port in that range may be handed to another test's
    socket before the run binds it (seen: "Address already in use" while the kernels compiled)."""
    low = _ephemeral_low()
    first, last = (20000, low - 50) if low >= 22000 else (30000, 60000)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        start = first + s.getsockname()[1] % (last - first)
    for base in [*range(start, last, 50), *range(first, start, 50)]:
        if all(_free(base + d) for d in (0, 7, 8, 10, 20, 30)):
            return base
    raise RuntimeError("no free ports")
