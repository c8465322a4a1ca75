"""Fixtures for whole-swarm runs."""

from __future__ import annotations

import socket

import pytest


def _free(port: int) -> bool:
    for kind in (socket.SOCK_DGRAM, socket.SOCK_STREAM):
        with socket.socket(socket.AF_INET, kind) as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                return False
    return True


@pytest.fixture
def free_base_port() -> int:
    """A base port p with p + 10 i (vehicles) and p + 7, p + 8 (mesh) free on 127.0.0.1."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        start = s.getsockname()[1] % 20000 + 30000
    for base in range(start, 60000, 50):
        if all(_free(base + d) for d in (0, 7, 8, 10, 20, 30)):
            return base
    raise RuntimeError("no free ports")
