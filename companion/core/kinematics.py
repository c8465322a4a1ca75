"""UAV kinematics (eq. 2): constant speed, bounded turn per sampling step, constant altitude.

Two modes share one interface. *grid* (the paper's simulations): the UAV sits on cell centres,
its heading is a multiple of 45 degrees, and each step it turns by a multiple of 45 degrees within
the limit and moves to the adjacent cell in the new direction. *continuous*: eq. 2 integrated
exactly with a constant turn rate over the step (a circular arc); `arc_advance` is the integrator
the simulator uses at its physics rate too.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numba import njit

from companion.core.geometry import FloatArray

_EIGHTH = math.pi / 4


def arc_advance(
    x: FloatArray | float,
    y: FloatArray | float,
    heading: FloatArray | float,
    omega: FloatArray | float,
    speed: float,
    dt: float,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Eq. 2 integrated exactly over dt with constant turn rate omega (rad/s): a circular arc.

    The chord has length v dt sinc(omega dt / 2) and points along the mid-arc heading, a form
    that stays exact as omega -> 0 (no cancellation in sin(h1) - sin(h) over a tiny omega).
    """
    x, y, h, w = (np.asarray(a, dtype=float) for a in (x, y, heading, omega))
    half = w * dt / 2
    chord = speed * dt * np.sinc(half / np.pi)
    h1 = h + w * dt
    dx, dy = chord * np.cos(h + half), chord * np.sin(h + half)
    return x + dx, y + dy, h1


@njit(cache=True)
def reachable_positions(first_steps: FloatArray, x: float, y: float, heading: float) -> FloatArray:
    """Every position reachable one step from the pose (x, y, heading): shape (n_turns, 2).

    `first_steps` is `PathTree.first_steps`: eight tables, one per 45-degree heading (grid mode),
    or one table for heading 0 that is rotated (continuous mode).
    """
    tables, n = first_steps.shape[0], first_steps.shape[1]
    out = np.empty((n, 2))
    if tables == 8:
        o = first_steps[round(heading / _EIGHTH) % 8]
        for q in range(n):
            out[q, 0], out[q, 1] = x + o[q, 0], y + o[q, 1]
    else:
        c, s = math.cos(heading), math.sin(heading)
        for q in range(n):
            ox, oy = first_steps[0, q, 0], first_steps[0, q, 1]
            out[q, 0], out[q, 1] = x + c * ox - s * oy, y + s * ox + c * oy
    return out


@njit(cache=True)
def grid_advance(poses: FloatArray, turns: FloatArray, cell_size: float) -> FloatArray:
    """Grid-mode eq. 2 for every UAV: rows (x, y, heading) after one step with the given turns."""
    out = np.empty_like(poses)
    for i in range(poses.shape[0]):
        h1 = np.round((poses[i, 2] + turns[i]) / _EIGHTH) * _EIGHTH
        out[i, 0] = poses[i, 0] + cell_size * np.round(math.cos(h1))
        out[i, 1] = poses[i, 1] + cell_size * np.round(math.sin(h1))
        out[i, 2] = (h1 + math.pi) % (2 * math.pi) - math.pi
    return out


def wrap_angle(a: FloatArray | float) -> FloatArray:
    """Angle wrapped to [-pi, pi)."""
    return (np.asarray(a, dtype=float) + math.pi) % (2 * math.pi) - math.pi


@dataclass(frozen=True)
class Kinematics:
    """Eq. 2 per sampling step dT: turn options, one-step advance, and M-step path enumeration."""

    mode: str
    speed: float
    dt: float
    turn_limit: float
    cell_size: float

    @cached_property
    def turn_options(self) -> FloatArray:
        """Admissible turns per step (rad), straight first: |turn| <= omega_max."""
        if self.mode == "grid":
            k = math.floor(self.turn_limit / _EIGHTH + 1e-9)
            steps = [0] + [s for i in range(1, k + 1) for s in (-i, i)]
            return np.array(steps, dtype=float) * _EIGHTH
        return np.array([0.0, -self.turn_limit, self.turn_limit])

    def turn_sequences(self, horizon: int) -> FloatArray:
        """All turn sequences over the horizon (n_l = n_turns^M rows), fewest turns first.

        The order is the deterministic tie-break of the RHC: among equal scores the straightest
        path wins.
        """
        seqs = np.array(list(itertools.product(self.turn_options, repeat=horizon)), dtype=float)
        order = np.argsort(np.sum(np.abs(seqs), axis=1), kind="stable")
        return seqs[order]

    def advance(
        self,
        x: FloatArray | float,
        y: FloatArray | float,
        heading: FloatArray | float,
        turn: FloatArray | float,
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Pose after one sampling step with the given turn (rad)."""
        if self.mode == "grid":
            x, y, h, q = np.broadcast_arrays(*(np.asarray(a, dtype=float) for a in (x, y, heading, turn)))
            poses = np.stack([x.ravel(), y.ravel(), h.ravel()], axis=1)
            out = grid_advance(poses, np.ascontiguousarray(q.ravel()), self.cell_size)
            return out[:, 0].reshape(x.shape), out[:, 1].reshape(x.shape), out[:, 2].reshape(x.shape)
        x1, y1, h1 = arc_advance(x, y, heading, np.asarray(turn) / self.dt, self.speed, self.dt)
        return x1, y1, wrap_angle(h1)

    def advance_poses(self, poses: FloatArray, turns: FloatArray) -> FloatArray:
        """`advance` for rows (x, y, heading) of several UAVs at once."""
        if self.mode == "grid":
            return grid_advance(poses, turns, self.cell_size)
        return np.column_stack(self.advance(poses[:, 0], poses[:, 1], poses[:, 2], turns))

    def paths(
        self, x: float, y: float, heading: float, sequences: FloatArray
    ) -> tuple[FloatArray, FloatArray]:
        """Eq. 23: predicted path points w(k+m|k), m = 1..M, for every turn sequence.

        Returns (points of shape (n_l, M, 2), headings of shape (n_l, M)).
        """
        n_paths, horizon = sequences.shape
        px, py, ph = np.full(n_paths, x), np.full(n_paths, y), np.full(n_paths, heading)
        pts = np.empty((n_paths, horizon, 2))
        heads = np.empty((n_paths, horizon))
        for m in range(horizon):
            px, py, ph = self.advance(px, py, ph, sequences[:, m])
            pts[:, m, 0], pts[:, m, 1], heads[:, m] = px, py, ph
        return pts, heads


@dataclass(frozen=True)
class PathTree:
    """Every M-step path of eq. 23 relative to the UAV's pose, precomputed once.

    Grid mode keeps one table per 45-degree heading; continuous mode keeps the paths for heading 0
    and rotates them, since an arc of eq. 2 turns with the heading it starts from.
    """

    kinematics: Kinematics
    sequences: FloatArray
    offsets: FloatArray  # (headings, n_l, M, 2)
    turned: FloatArray  # (headings, n_l, M): heading change after each step

    @classmethod
    def build(cls, kin: Kinematics, horizon: int) -> PathTree:
        seqs = kin.turn_sequences(horizon)
        starts = np.arange(8) * _EIGHTH if kin.mode == "grid" else np.zeros(1)
        offsets = np.empty((len(starts), len(seqs), horizon, 2))
        turned = np.empty((len(starts), len(seqs), horizon))
        for i, h0 in enumerate(starts):
            pts, heads = kin.paths(0.0, 0.0, float(h0), seqs)
            offsets[i], turned[i] = pts, heads - h0
        return cls(kin, seqs, offsets, turned)

    @cached_property
    def max_step(self) -> float:
        """The longest distance a UAV can move in one step (grid: a diagonal)."""
        return float(np.max(np.linalg.norm(self.offsets[:, :, 0, :], axis=-1)))

    def _table(self, heading: float) -> int:
        return round(heading / _EIGHTH) % 8 if self.kinematics.mode == "grid" else 0

    def offsets_from(self, heading: float) -> FloatArray:
        """The path points relative to the UAV's position (n_l, M, 2) for a grid-mode `heading`."""
        return self.offsets[self._table(heading)]

    def expand(self, x: float, y: float, heading: float) -> FloatArray:
        """Path points w(k+m|k) of shape (n_l, M, 2) from the pose (x, y, heading)."""
        o = self.offsets[self._table(heading)]
        if self.kinematics.mode == "grid":
            return o + np.array((x, y))
        c, s = math.cos(heading), math.sin(heading)
        return np.stack([x + c * o[..., 0] - s * o[..., 1], y + s * o[..., 0] + c * o[..., 1]], axis=-1)

    @cached_property
    def first_steps(self) -> FloatArray:
        """Per heading table, the distinct first-step offsets (one per turn option)."""
        return np.stack([np.unique(table[:, 0, :].round(9), axis=0) for table in self.offsets])

    def headings_along(self, heading: float, path: int) -> tuple[float, ...]:
        """The heading after each step of path `path` from `heading`, wrapped to [-pi, pi)."""
        if self.kinematics.mode == "grid":
            return self._grid_headings[self._table(heading)][path]
        return tuple(((heading + self.turned[0, path] + math.pi) % (2 * math.pi) - math.pi).tolist())

    @cached_property
    def _grid_headings(self) -> list[list[tuple[float, ...]]]:
        """Grid mode: `headings_along` for each of the eight start headings and every path."""
        wrapped = (np.arange(8)[:, None, None] * _EIGHTH + self.turned + math.pi) % (2 * math.pi) - math.pi
        return [[tuple(row) for row in table.tolist()] for table in wrapped]
