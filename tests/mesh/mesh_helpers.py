"""Shared by the mesh tests and their subprocess peer: missions on fresh loopback ports, outboxes."""

from __future__ import annotations

import socket
import time
import uuid
from collections.abc import Callable
from pathlib import Path

import msgspec

from companion.contracts.mission import Mission
from companion.core.feasibility import load_mission
from companion.core.messages import BidsMsg, CoverageMsg, Message, StateMsg, UavState

ROOT = Path(__file__).resolve().parents[2]
N_CELLS, N_TASKS = 2500, 4


def free_endpoint() -> str:
    """A loopback TCP endpoint on a port the OS just handed out."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


def make_mission(loss: float = 0.0, mode: str = "peer", **mesh: object) -> Mission:
    """Scenario 1 (4 UAVs, R_c = 1000 m) with a unique key prefix and fresh seed/router endpoints."""
    base = load_mission(ROOT / "mission_files/scenario1.toml")
    fields = {
        "mode": mode,
        "key_prefix": f"test{uuid.uuid4().hex[:10]}",
        "seed_endpoint": free_endpoint(),
        "router": free_endpoint(),
        **mesh,
    }
    return msgspec.structs.replace(
        base,
        comms=msgspec.structs.replace(base.comms, loss=loss),
        mesh=msgspec.structs.replace(base.mesh, **fields),
    )


def outbox(uav: int, step: int, x: float, y: float) -> list[Message]:
    """A valid outbox of three messages stamped `step` at (x, y)."""
    state = UavState(uav=uav, stamp=step, x=x, y=y, heading=0.5, plan=((x, y + 40.0),))
    head = {"sender": uav, "stamp": step, "x": x, "y": y}
    return [
        StateMsg(**head, state=state),
        CoverageMsg(**head, cells=(uav, step % N_CELLS)),
        BidsMsg(**head, rewards=(0.25,) * N_TASKS),
    ]


def until(predicate: Callable[[], bool], timeout: float = 10.0) -> bool:
    """Poll `predicate` until it holds or a generous `timeout` passes."""
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.02)
    return True
