"""Mesh faults a companion injects into its own inbox, by step (the mission's `[faults]`).

Partitions and message loss over windows of steps, for the fault matrix (docs/reliability.md).
Deterministic: the windows are in steps, and the loss draws come from the companion's own seeded
stream, one draw per message that survives the partition, in delivery order.
"""

from __future__ import annotations

import numpy as np

from companion.contracts.mission import Mission
from companion.core.messages import Message


class InjectedFaults:
    """UAV `uav`'s filter of its step-k inbox; `dropped` counts what it took out."""

    def __init__(self, mission: Mission, uav: int, rng: np.random.Generator) -> None:
        self.uav, self.rng = uav, rng
        self.windows = mission.faults.network
        self.dropped = 0

    def active(self, k: int) -> bool:
        return any(f.start <= k < f.end for f in self.windows)

    def filter(self, k: int, inbox: list[Message]) -> list[Message]:
        """The messages of `inbox` (stamped k - 1) that the faults in force at step k let through."""
        out = inbox
        for f in self.windows:
            if not f.start <= k < f.end:
                continue
            if f.groups:
                mine = next((set(g) for g in f.groups if self.uav in g), {self.uav})
                out = [m for m in out if m.sender in mine]
            if f.loss > 0:
                out = [m for m in out if self.rng.random() >= f.loss]
        self.dropped += len(inbox) - len(out)
        return out
