"""Fixtures for whole-swarm runs."""

from __future__ import annotations

import pytest

from companion.app.loopback import free_blocks


@pytest.fixture
def free_base_port() -> int:
    """A base port p with p + 10 i (vehicles) and p + 7, p + 8 (mesh) free on 127.0.0.1, below the
    ephemeral range (companion.app.loopback)."""
    return free_blocks(1, width=31, spacing=50)[0]
