"""The fleet's motion: constant speed, bounded turns, altitude flown to its target as ArduPlane does.

Guidance asks every vehicle for a bank angle (with the command's own bank limit) or a turn rate,
counter-clockwise positive; a flight model turns that into motion at `substeps` physics ticks per
step: `KinematicFlight` (eq. 2 integrated with `arc_advance`), `BankedFlight` (the roll as a
first-order lag, turning as ArduPlane SITL's plane) or `GridFlight` (`Kinematics.advance` exactly).
Every model climbs and sinks to the commanded altitude (`Flight._climb`) within ArduPlane's limits.
The models and their measurements: docs/simulator.md, "Dynamics".
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from companion.core.geometry import FloatArray
from companion.core.kinematics import Kinematics, arc_advance, wrap_angle
from sim_vehicles.dynamics.navigation import GRAVITY

CLIMB_MAX, SINK_MAX = 5.0, 5.0  # m/s: ArduPlane's TECS_CLMB_MAX, TECS_SINK_MAX (plane.parm; measured 4.8)
DEMAND_TCONST = 2.0  # s: how the height demand closes on a commanded altitude
HEIGHT_TCONST, CLIMB_TCONST = 1.0, 2.8  # s: the height loop (period ~11 s, damping 0.3, as measured)
ROLL_KICK = 0.28  # m/s of climb per unit of n^4 gained (banked model; fitted to ArduPlane SITL)
ROLL_TCONST = 0.5  # s: the roll's response to its demand (ArduPlane SITL, measured)
ROLL_RATE_MAX = math.radians(90.0)  # rad/s (plane.parm's RLL2SRV_RMAX)
TURN_EFFICIENCY = 0.7  # heading rate / (g tan(roll) / v) of ArduPlane SITL's plane (measured)
_EIGHTH = math.pi / 4


@dataclass
class Demand:
    """What the fleet's guidance asks for this tick, one entry per vehicle."""

    by_bank: FloatArray  # 1: fly `bank`; 0: fly `rate`
    bank: FloatArray  # bank angle (rad, CCW positive)
    rate: FloatArray  # turn rate (rad/s, CCW positive)
    bank_limit: FloatArray  # the command's own bank limit (rad)
    moving: FloatArray  # 1 armed (flying), 0 frozen
    speed: FloatArray  # m/s
    turn_limit: FloatArray  # rad per step (kinematic and grid models)
    roll_limit: FloatArray  # rad (banked model)

    @classmethod
    def empty(cls, n: int) -> Demand:
        return cls(*(np.zeros(n) for _ in range(8)))

    def ideal_rate(self) -> FloatArray:
        """The turn rate asked for, a bank read as the ideal coordinated turn g tan(bank) / v."""
        banked = GRAVITY * np.tan(self.bank) / np.maximum(self.speed, 1.0)
        return np.where(self.by_bank > 0, banked, self.rate)


class Flight:
    """Fleet state shared by the models: pose, velocity, turn rate, roll and altitude arrays."""

    def __init__(self, poses: FloatArray, alt: FloatArray, step: float, substeps: int) -> None:
        n = poses.shape[0]
        self.x, self.y = poses[:, 0].astype(float), poses[:, 1].astype(float)
        self.heading = wrap_angle(poses[:, 2])
        self.alt, self.alt_target = np.array(alt, dtype=float), np.array(alt, dtype=float)
        self.alt_demand = np.array(alt, dtype=float)
        self.vx, self.vy, self.vz, self.omega, self.roll = (np.zeros(n) for _ in range(5))
        self.roll_kick = 0.0  # m/s of climb per unit of n^4 gained (the banked model's)
        self._load_before = np.ones(n)
        self.step, self.substeps = step, substeps
        self.dt = step / substeps

    def needs_demand(self) -> bool:
        """Whether this tick uses the guidance's demands."""
        return True

    def tick(self, d: Demand) -> None:
        raise NotImplementedError

    def _advance(self, w: FloatArray, v: FloatArray) -> None:
        x1, y1, h1 = arc_advance(self.x, self.y, self.heading, w, v, self.dt)  # type: ignore[arg-type]
        self.vx, self.vy = (x1 - self.x) / self.dt, (y1 - self.y) / self.dt
        self.x, self.y, self.heading, self.omega = x1, y1, wrap_angle(h1), w
        self._climb()

    def _climb(self) -> None:
        """One tick of the height loop (see the module's docstring)."""
        dt = self.dt
        rate = np.clip((self.alt_target - self.alt_demand) / DEMAND_TCONST, -SINK_MAX, CLIMB_MAX)
        self.alt_demand += rate * dt
        want = np.clip(rate + (self.alt_demand - self.alt) / HEIGHT_TCONST, -SINK_MAX, CLIMB_MAX)
        load = 1.0 / np.cos(np.clip(self.roll, -1.4, 1.4)) ** 4
        kick = self.roll_kick * (load - self._load_before)
        self._load_before = load
        self.vz = self.vz + (want - self.vz) * min(dt / CLIMB_TCONST, 1.0) + kick
        self.alt += self.vz * dt


class KinematicFlight(Flight):
    """Eq. 2 integrated with `arc_advance` at the physics rate: instant turns within the limit."""

    def tick(self, d: Demand) -> None:
        w = np.clip(d.ideal_rate(), -d.turn_limit / self.step, d.turn_limit / self.step) * d.moving
        self.roll = np.arctan(w * d.speed / GRAVITY)
        self._advance(w, d.speed * d.moving)


class BankedFlight(Flight):
    """Coordinated turns with a lagged, rate-limited roll (ArduPlane-like).

    The model includes the roll's effect on the altitude.
    """

    def __init__(self, poses: FloatArray, alt: FloatArray, step: float, substeps: int) -> None:
        super().__init__(poses, alt, step, substeps)
        self.roll_kick = ROLL_KICK

    def tick(self, d: Demand) -> None:
        v = np.maximum(d.speed, 1.0)
        limit = np.minimum(d.bank_limit, d.roll_limit)
        for_rate = np.arctan(d.rate * v / (GRAVITY * TURN_EFFICIENCY))
        want = np.clip(np.where(d.by_bank > 0, d.bank, for_rate), -limit, limit)
        change = np.clip(
            (want - self.roll) * min(self.dt / ROLL_TCONST, 1.0),
            -ROLL_RATE_MAX * self.dt,
            ROLL_RATE_MAX * self.dt,
        )
        self.roll = (self.roll + change) * d.moving
        self._advance(TURN_EFFICIENCY * GRAVITY * np.tan(self.roll) / v, d.speed * d.moving)


class GridFlight(Flight):
    """Eq. 2's grid mode: one cell per step, exactly as `Kinematics.advance`.

    Within the step the pose is interpolated linearly.
    """

    def __init__(
        self, poses: FloatArray, alt: FloatArray, step: float, substeps: int, kinematics: Kinematics
    ) -> None:
        super().__init__(poses, alt, step, substeps)
        self.kinematics = kinematics
        self.x0, self.y0 = self.x.copy(), self.y.copy()
        self.x1, self.y1 = self.x.copy(), self.y.copy()
        self.j = 0  # ticks into the current step

    def needs_demand(self) -> bool:
        return self.j == 0

    def tick(self, d: Demand) -> None:
        if self.j == 0:
            k = np.floor(d.turn_limit / _EIGHTH + 1e-9)
            q = np.clip(np.round(d.ideal_rate() * self.step / _EIGHTH), -k, k) * _EIGHTH
            x1, y1, h1 = self.kinematics.advance(self.x, self.y, self.heading, q)
            go = d.moving > 0
            self.x0, self.y0 = self.x.copy(), self.y.copy()
            self.x1, self.y1 = np.where(go, x1, self.x), np.where(go, y1, self.y)
            self.heading = np.where(go, h1, self.heading)
            self.omega = np.where(go, q / self.step, 0.0)
            self.roll = np.arctan(self.omega * self.kinematics.speed / GRAVITY)
            self.vx, self.vy = (self.x1 - self.x0) / self.step, (self.y1 - self.y0) / self.step
        self.j += 1
        if self.j == self.substeps:
            self.x, self.y, self.j = self.x1.copy(), self.y1.copy(), 0
        else:
            f = self.j / self.substeps
            self.x, self.y = self.x0 + f * (self.x1 - self.x0), self.y0 + f * (self.y1 - self.y0)
        self._climb()
