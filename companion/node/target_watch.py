"""Candidate and confirmed targets, told apart step by step for the companion's logs and report.

The agent's map (`Agent.belief`) holds each cell's posterior; `Agent.found` is the set of cells
whose posterior reached the mission's `sensor.confirm`, `Agent.candidates` the cells a detection
left undecided. `TargetWatch` compares them with the previous step's and names what changed: a new
candidate, a confirmation, a retraction (a confirmed cell fallen back below the threshold), each
with its cell's centre in the local frame and in latitude/longitude, and its posterior.
"""

from __future__ import annotations

import logging

import msgspec
import numpy as np

from companion.contracts.frames import LocalFrame
from companion.core.agent import Agent

log = logging.getLogger("companion")

CANDIDATE, CONFIRMED, RETRACTED = "candidate", "confirmed", "retracted"


class TargetEvent(msgspec.Struct, frozen=True):
    """One change of a cell's standing: `event` is candidate, confirmed or retracted."""

    step: int
    event: str
    cell: int
    x: float
    y: float
    lat: float
    lon: float
    posterior: float


class TargetWatch:
    """What one companion's map decided about targets, step by step (`step`), and the run's counts."""

    def __init__(self, uav: int, frame: LocalFrame, agent: Agent) -> None:
        """Start from what `agent` holds (a companion restarted from its journal logged the rest)."""
        self.uav, self.frame = uav, frame
        self.confirmed: set[int] = set(agent.found)
        self.candidates: set[int] = set(agent.candidates.tolist())
        self.counts = {CANDIDATE: 0, CONFIRMED: 0, RETRACTED: 0}

    def step(self, k: int, agent: Agent) -> list[TargetEvent]:
        """Step k's new candidates, confirmations and retractions, each logged; returned in cell order."""
        confirmed, candidates = set(agent.found), set(agent.candidates.tolist())
        changes = [(c, CONFIRMED) for c in confirmed - self.confirmed]
        changes += [(c, RETRACTED) for c in self.confirmed - confirmed]
        changes += [(c, CANDIDATE) for c in candidates - self.candidates - self.confirmed]
        self.confirmed, self.candidates = confirmed, candidates
        if not changes:
            return []
        changes.sort()
        cells = np.array([c for c, _ in changes], dtype=np.int64)
        posterior = agent.belief.posterior(cells)
        centres = agent.world.grid.centres
        events = []
        for (cell, event), p in zip(changes, posterior.tolist(), strict=True):
            x, y = (float(v) for v in centres[cell])
            lat, lon, _ = self.frame.to_geodetic(x, y)
            events.append(TargetEvent(k, event, cell, x, y, lat, lon, p))
            self.counts[event] += 1
            log.info(
                "uav %d: step %d: %s target, cell %d at (%.1f, %.1f) m, %.7f %.7f, posterior %.6f",
                self.uav, k, event, cell, x, y, lat, lon, p,
            )  # fmt: skip
        return events
