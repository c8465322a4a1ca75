"""Committed trajectories: a plan of M turns from an anchor pose, then a loiter forever.

A trajectory is what a UAV promises to fly if nothing else is agreed: from its anchor pose at step
`start` it takes the M planned turns of eq. 2, then turns by the loiter turn (the largest turn
allowed per step, in direction `loiter` = +1 CCW or -1 CW) at every step after, which closes a
circle (continuous mode) or an octagon of cells (grid mode). Every trajectory is therefore a
contingency: followed forever, it keeps the UAV inside a bounded set (`Reach.extent`).

For the compiled kernels a trajectory is one row `(start, x, y, heading, loiter, turn_1..turn_M)`.
Positions between sampling moments: grid mode flies straight from cell centre to cell centre
(as the simulator does); continuous mode flies circular arcs, which deviate from their chords by
at most the sagitta `Reach.sagitta` (`arc_chord_deviation`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import msgspec
import numpy as np
from numba import njit

from companion.core.geometry import FloatArray
from companion.core.kinematics import Kinematics

HEAD = 5  # columns of a trajectory row before its turns: start, x, y, heading, loiter
_EIGHTH = math.pi / 4


class Trajectory(msgspec.Struct, frozen=True, array_like=True):
    """A committed trajectory on the wire: anchor step and pose, the planned turns, loiter side."""

    start: int
    x: float
    y: float
    heading: float
    turns: tuple[float, ...]
    loiter: int  # +1 counter-clockwise, -1 clockwise

    def fields(self, horizon: int) -> tuple[float, ...]:
        """The kernel row; turns missing from a short plan are NaN.

        `expand` then takes the loiter turn.
        """
        turns = self.turns[:horizon]
        row = (self.start, self.x, self.y, self.heading, self.loiter, *turns)
        return row if len(turns) == horizon else row + (math.nan,) * (horizon - len(turns))

    def turn_at(self, step: int, loiter_turn: float) -> float:
        """The turn this trajectory takes over [t_step, t_step+1]."""
        i = step - self.start
        return self.turns[i] if 0 <= i < len(self.turns) else self.loiter * loiter_turn

    def loiter_entry(self, loiter_turn: float) -> int:
        """The step from which it only loiters: after its last turn that is not the loiter's.

        `reanchored` pads with loiter turns; a plan ending in them is on the loiter circle already.
        """
        turn = self.loiter * loiter_turn
        planned = len(self.turns)
        while planned and abs(self.turns[planned - 1] - turn) < 1e-12:
            planned -= 1
        return self.start + planned

    def reanchored(self, step: int, x: float, y: float, heading: float, loiter_turn: float) -> Trajectory:
        """The same promise anchored at `step` at the pose (x, y, heading).

        The turns still ahead, then loiter turns, so that every row keeps M turns.
        """
        i = max(step - self.start, 0)
        ahead = self.turns[i:] + (self.loiter * loiter_turn,) * min(i, len(self.turns))
        return Trajectory(step, x, y, heading, ahead, self.loiter)


@njit(cache=True)
def step_pose(
    x: float, y: float, h: float, turn: float, grid: bool, speed: float, dt: float, cell: float
) -> tuple[float, float, float]:
    """Eq. 2 over one step: `Kinematics.advance` for one UAV, heading wrapped to [-pi, pi).

    Grid mode is `grid_advance`; continuous mode is `arc_advance`'s chord form.
    """
    if grid:
        h1 = round((h + turn) / _EIGHTH) * _EIGHTH
        x1 = x + cell * round(math.cos(h1))
        y1 = y + cell * round(math.sin(h1))
    else:
        half = turn / 2
        chord = speed * dt * (math.sin(half) / half if half != 0.0 else 1.0)
        x1 = x + chord * math.cos(h + half)
        y1 = y + chord * math.sin(h + half)
        h1 = h + turn
    return x1, y1, (h1 + math.pi) % (2 * math.pi) - math.pi


@njit(cache=True)
def expand(
    row: FloatArray,
    first: int,
    count: int,
    loiter_turn: float,
    grid: bool,
    speed: float,
    dt: float,
    cell: float,
) -> FloatArray:
    """Positions of trajectory `row` at steps first..first+count (count + 1 points).

    Turns that are NaN (past the plan) and steps beyond the plan take the loiter turn; steps before
    the anchor (never asked for by the safety layer, which checks trajectories from their start on)
    hold the anchor.
    """
    start = int(row[0])
    x, y, h = row[1], row[2], row[3]
    side = row[4]
    horizon = row.shape[0] - HEAD
    out = np.empty((count + 1, 2))
    for early in range(min(max(start - first, 0), count + 1)):
        out[early, 0], out[early, 1] = x, y
    if start > first + count:
        return out
    t = start
    while True:
        if t >= first:
            out[t - first, 0], out[t - first, 1] = x, y
            if t == first + count:
                break
        i = t - start
        turn = row[HEAD + i] if i < horizon else np.nan
        if math.isnan(turn):
            turn = side * loiter_turn
        x, y, h = step_pose(x, y, h, turn, grid, speed, dt, cell)
        t += 1
    return out


@njit(cache=True)
def segment_clearance(a: FloatArray, b: FloatArray) -> float:
    """The closest approach of two UAVs moving uniformly along their chords, over every step.

    The chords are a[t] -> a[t+1] and b[t] -> b[t+1] for every step t; exact for straight motion.
    """
    best = math.inf
    for t in range(a.shape[0] - 1):
        rx, ry = a[t, 0] - b[t, 0], a[t, 1] - b[t, 1]
        dx = a[t + 1, 0] - b[t + 1, 0] - rx
        dy = a[t + 1, 1] - b[t + 1, 1] - ry
        dd = dx * dx + dy * dy
        s = 0.0 if dd == 0.0 else min(max(-(rx * dx + ry * dy) / dd, 0.0), 1.0)
        best = min(best, math.hypot(rx + s * dx, ry + s * dy))
    return best


@njit(cache=True)
def point_clearance(a: FloatArray, cx: float, cy: float) -> float:
    """The closest approach of the polyline a (chords between sampling moments) to the point (cx, cy)."""
    best = math.inf
    for t in range(a.shape[0] - 1):
        rx, ry = a[t, 0] - cx, a[t, 1] - cy
        dx, dy = a[t + 1, 0] - a[t, 0], a[t + 1, 1] - a[t, 1]
        dd = dx * dx + dy * dy
        s = 0.0 if dd == 0.0 else min(max(-(rx * dx + ry * dy) / dd, 0.0), 1.0)
        best = min(best, math.hypot(rx + s * dx, ry + s * dy))
    return best


def arc_chord_deviation(turn: float, speed: float, dt: float) -> float:
    """The sagitta R (1 - cos(turn / 2)): how far an arc of eq. 2 strays from its chord.

    It is the largest distance, at equal times, between a UAV on a circular arc turning `turn` in dt
    and a point moving uniformly along the arc's chord.
    """
    if turn == 0:
        return 0.0
    radius = speed * dt / abs(turn)
    return radius * (1 - math.cos(abs(turn) / 2))


@dataclass(frozen=True)
class Reach:
    """Bounds every trajectory of a mission obeys (derived once from eq. 2 and the horizon M).

    - `loiter_turn`: the loiter's turn per step (the largest admissible turn).
    - `period`: steps after which two loitering UAVs are back in the same relative configuration
      (the loiter closes after 2 pi / loiter_turn steps; rounded up).
    - `step`: the farthest a UAV moves in one step.
    - `extent`: the farthest any point of a trajectory lies from its position at any step of it
      (M plan steps, then the loiter's diameter).
    - `sagitta`: how far a UAV strays from the chord between two sampling moments (0 in grid mode).
    - `window`: steps of two trajectories to compare so that every later step repeats one of them.
    """

    loiter_turn: float
    period: int
    step: float
    extent: float
    sagitta: float
    window: int

    @classmethod
    def of(cls, kin: Kinematics, horizon: int) -> Reach:
        turn = float(np.max(np.abs(kin.turn_options)))
        period = math.ceil(2 * math.pi / turn - 1e-9)
        grid = kin.mode == "grid"
        step = kin.cell_size * math.sqrt(2.0) if grid else kin.speed * kin.dt
        row = np.full(HEAD + horizon, np.nan)
        row[:HEAD] = (0, 0.0, 0.0, 0.0, 1.0)
        loop = expand(row, horizon, period, turn, grid, kin.speed, kin.dt, kin.cell_size)
        diameter = float(np.max(np.linalg.norm(loop[:, None, :] - loop[None, :, :], axis=-1)))
        sagitta = 0.0 if grid else arc_chord_deviation(turn, kin.speed, kin.dt)
        extent = horizon * step + diameter + 2 * sagitta
        return cls(turn, period, step, extent, sagitta, horizon + period + 1)
