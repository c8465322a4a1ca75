"""The aircraft of a UAV whose companion died, as the batch engine flies it (eq. 2 kinematics).

It does what ArduPlane does once it stops hearing its companion (docs/companion.md, "The failsafe
for a silent companion"). (A) It holds its last command, the turn of the companion's last step,
until the GCS failsafe fires `Mission.failsafe_seconds` plus one failsafe check later (whole
steps, rounded down: the safety layer's bound, `world.failsafe_stray`, covers the rest). (B) In
AUTO it flies to the failsafe loiter, the loiter circle of the last trajectory in force its
companion published (`Limits.loiter_circle`), towards the tangent on the loiter's side, at the
turns eq. 2 allows. (C) Within half a step of that circle it circles for good at the loiter
turn, on the loiter's side, at a phase and about a centre of its own.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from companion.core.trajectory import Trajectory
from companion.core.world import FAILSAFE_CHECK_S, World


@dataclass
class DeadVehicle:
    """One dead companion's aircraft from its death on: `turn(k, pose)` is its turn at step k."""

    held: float  # the last command's turn, flown for `hold` steps from `death`
    death: int
    hold: int
    centre: tuple[float, float]
    radius: float
    side: int  # the loiter's side: +1 counter-clockwise (turning left), -1 clockwise
    options: np.ndarray  # the admissible turns of eq. 2
    loiter_turn: float
    capture: float  # how near the circle it starts circling (half a step)
    circling: bool = False

    @classmethod
    def of(cls, world: World, death: int, held: float, inforce: Trajectory) -> DeadVehicle:
        m, lim = world.mission, world.safety.limits
        hold = int((m.failsafe_seconds + FAILSAFE_CHECK_S) // m.kinematics.step)
        cx, cy, r = lim.loiter_circle(inforce)
        return cls(
            held,
            death,
            hold,
            (cx, cy),
            r,
            inforce.loiter,
            np.asarray(world.kinematics.turn_options, dtype=float),
            lim.reach.loiter_turn,
            lim.reach.step / 2,
        )

    def turn(self, k: int, x: float, y: float, heading: float) -> float:
        if k < self.death + self.hold:
            return self.held
        cx, cy = self.centre
        d = math.hypot(cx - x, cy - y)
        if self.circling or d <= self.radius + self.capture:
            self.circling = True
            return self.side * self.loiter_turn
        # towards the tangent point that leaves the centre on the loiter's side
        bearing = math.atan2(cy - y, cx - x)
        wanted = bearing - self.side * math.asin(min(1.0, self.radius / d))
        errors = np.abs(np.angle(np.exp(1j * (heading + self.options - wanted))))
        return float(self.options[int(np.argmin(errors))])
