"""The simulator's state file: a restarted simulator goes on where it stopped (`--state FILE`).

At every sampling-step boundary the host writes its whole state (time, every vehicle's flight
state and autopilot state, the lockstep step) to FILE, atomically
(a temporary file renamed over it), and a simulator started with an existing FILE resumes from it:
same time, same poses, same modes and guidance, as an aircraft whose simulator process was
restarted would be. The file is a pickle: only ever load one this simulator wrote.
"""

from __future__ import annotations

import hashlib
import os
import pickle
from pathlib import Path
from typing import TYPE_CHECKING, Any

import msgspec

from sim_vehicles.clock import LockstepClock, RealTimeClock

if TYPE_CHECKING:
    from sim_vehicles.host import Host

STATE_VERSION = 1
_NOT_SAVED = {"kinematics"}  # rebuilt from the mission


UNREADABLE = (OSError, EOFError, pickle.UnpicklingError, KeyError, TypeError, AttributeError, ImportError)


class StateError(ValueError):
    """A state file that cannot be resumed from (the message says why)."""


def _identity(host: Host) -> tuple[int, str, int]:
    digest = hashlib.sha256(msgspec.msgpack.encode(host.mission)).hexdigest()[:32]
    return STATE_VERSION, digest, host.seed


def save_state(host: Host, path: Path) -> None:
    """Write the host's state to `path` (atomically)."""
    state: dict[str, Any] = {
        "identity": _identity(host),
        "tick": host.tick,
        "epoch": host.unix_epoch_usec,
        "flight": {k: v for k, v in vars(host.flight).items() if k not in _NOT_SAVED},
        "vehicles": [vars(hv.vehicle) for hv in host.hosted],
        "next_camera": getattr(host, "next_camera", 0.0),
    }
    tmp = path.with_name(path.name + ".tmp")
    with tmp.open("wb") as f:
        pickle.dump(state, f, protocol=pickle.HIGHEST_PROTOCOL)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def load_state(host: Host, path: Path) -> None:
    """Put the host back in the state saved at `path`; raises StateError if it is another mission's."""
    try:
        with path.open("rb") as f:
            state = pickle.load(f)
        identity = state["identity"]
    except UNREADABLE as exc:  # a class pickled by another version: AttributeError, ImportError
        raise StateError(f"state file {path}: unreadable ({exc}): remove it to start afresh") from None
    if identity != _identity(host):
        raise StateError(f"state file {path}: saved by another mission, seed or version: remove it")
    host.tick = state["tick"]
    host.unix_epoch_usec = state["epoch"]
    vars(host.flight).update(state["flight"])
    for hv, saved in zip(host.hosted, state["vehicles"], strict=True):
        vars(hv.vehicle).update(saved)
    host.next_camera = state["next_camera"]
    if isinstance(host.clock, LockstepClock):  # saved on step boundaries: the step of the saved tick
        host.clock.step = host.snapshot_step = host.tick // host.substeps
    elif isinstance(host.clock, RealTimeClock):
        host.clock.origin_tick = host.tick
