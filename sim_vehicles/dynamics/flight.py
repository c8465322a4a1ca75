"""Eq. 2 for the whole fleet: constant speed, bounded turn, altitude slewed to its target.

The guidance of every vehicle expresses its wish as a *turn per sampling step* dT (radians, CCW
positive), the quantity of the paper. The flight models turn it into motion:

- `ContinuousFlight` integrates eq. 2 with `arc_advance` at the physics rate, with turn rate
  `turn / dT` limited to the vehicle's turn limit per dT.
- `GridFlight` reproduces `Kinematics.advance` exactly: at each step boundary it quantises the
  turn to a multiple of 45 degrees within the limit, computes the next cell with the core's own
  `advance`, and moves linearly from cell centre to cell centre during the step.

Both tick at `substeps` physics ticks per step, so step boundaries fall exactly on ticks.
"""

from __future__ import annotations

import math

import numpy as np

from companion.core.geometry import FloatArray
from companion.core.kinematics import Kinematics, arc_advance, wrap_angle

CLIMB_RATE = 3.0  # m/s, the rate altitude changes are flown at
_EIGHTH = math.pi / 4


class Flight:
    """Fleet state shared by both models: pose, velocity and altitude arrays."""

    def __init__(self, poses: FloatArray, alt: float, step: float, substeps: int) -> None:
        n = poses.shape[0]
        self.x, self.y = poses[:, 0].astype(float), poses[:, 1].astype(float)
        self.heading = wrap_angle(poses[:, 2])
        self.alt, self.alt_target = np.full(n, alt), np.full(n, alt)
        self.vx, self.vy, self.vz, self.omega = (np.zeros(n) for _ in range(4))
        self.step, self.substeps = step, substeps
        self.dt = step / substeps

    def needs_demand(self) -> bool:
        """Whether this tick uses the guidance's turn demands."""
        return True

    def tick(self, turn: FloatArray, moving: FloatArray, speed: FloatArray, limit: FloatArray) -> None:
        """Advance one physics tick; `limit` is each vehicle's turn limit per step (rad)."""
        raise NotImplementedError

    def _climb(self) -> None:
        d = np.clip(self.alt_target - self.alt, -CLIMB_RATE * self.dt, CLIMB_RATE * self.dt)
        self.alt += d
        self.vz = d / self.dt


class ContinuousFlight(Flight):
    """Eq. 2 integrated with `arc_advance` at the physics rate."""

    def tick(self, turn: FloatArray, moving: FloatArray, speed: FloatArray, limit: FloatArray) -> None:
        w = np.clip(turn, -limit, limit) / self.step * moving
        v = speed * moving
        x1, y1, h1 = arc_advance(self.x, self.y, self.heading, w, v, self.dt)  # type: ignore[arg-type]
        self.vx, self.vy = (x1 - self.x) / self.dt, (y1 - self.y) / self.dt
        self.x, self.y, self.heading, self.omega = x1, y1, wrap_angle(h1), w
        self._climb()


class GridFlight(Flight):
    """One cell per step exactly as `Kinematics.advance`, interpolated linearly within the step."""

    def __init__(
        self, poses: FloatArray, alt: float, step: float, substeps: int, kinematics: Kinematics
    ) -> None:
        super().__init__(poses, alt, step, substeps)
        self.kinematics = kinematics
        self.x0, self.y0 = self.x.copy(), self.y.copy()
        self.x1, self.y1 = self.x.copy(), self.y.copy()
        self.j = 0  # ticks into the current step

    def needs_demand(self) -> bool:
        return self.j == 0

    def tick(self, turn: FloatArray, moving: FloatArray, speed: FloatArray, limit: FloatArray) -> None:
        if self.j == 0:
            k = np.floor(limit / _EIGHTH + 1e-9)
            q = np.clip(np.round(turn / _EIGHTH), -k, k) * _EIGHTH
            x1, y1, h1 = self.kinematics.advance(self.x, self.y, self.heading, q)
            go = moving > 0
            self.x0, self.y0 = self.x.copy(), self.y.copy()
            self.x1, self.y1 = np.where(go, x1, self.x), np.where(go, y1, self.y)
            self.heading = np.where(go, h1, self.heading)
            self.omega = np.where(go, q / self.step, 0.0)
            self.vx, self.vy = (self.x1 - self.x0) / self.step, (self.y1 - self.y0) / self.step
        self.j += 1
        if self.j == self.substeps:
            self.x, self.y, self.j = self.x1.copy(), self.y1.copy(), 0
        else:
            f = self.j / self.substeps
            self.x, self.y = self.x0 + f * (self.x1 - self.x0), self.y0 + f * (self.y1 - self.y0)
        self._climb()
