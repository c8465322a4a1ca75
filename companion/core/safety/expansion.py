"""Trajectory rows expanded into positions over the window, and their loiters' centres."""

from __future__ import annotations

import numpy as np
from numba import njit

from companion.core.geometry import FloatArray, IntArray
from companion.core.trajectory import HEAD, expand


@njit(cache=True)
def loiter_centre(pts: FloatArray, first: int) -> tuple[float, float]:
    """The centre of a loiter from three consecutive sampling points: their circumcentre.

    The centre of the loiter whose sampling points are pts[first:] (at least three of them, all
    of them if `first` < 0): the circumcentre of three consecutive ones (grid mode's loiter octagon
    has concyclic vertices)."""
    i = min(max(first, 0), pts.shape[0] - 3)
    ax, ay, bx, by, cx, cy = pts[i, 0], pts[i, 1], pts[i + 1, 0], pts[i + 1, 1], pts[i + 2, 0], pts[i + 2, 1]
    d = 2 * (ax * (by - cy) + bx * (cy - ay) + cx * (ay - by))
    a2, b2, c2 = ax * ax + ay * ay, bx * bx + by * by, cx * cx + cy * cy
    ux = (a2 * (by - cy) + b2 * (cy - ay) + c2 * (ay - by)) / d
    uy = (a2 * (cx - bx) + b2 * (ax - cx) + c2 * (bx - ax)) / d
    return ux, uy


@njit(cache=True)
def loiter_centres(pts: FloatArray, firsts: IntArray) -> FloatArray:
    """`loiter_centre` of every expanded trajectory pts[r] from its index firsts[r]: (n, 2)."""
    out = np.empty((pts.shape[0], 2))
    for r in range(pts.shape[0]):
        out[r, 0], out[r, 1] = loiter_centre(pts[r], firsts[r])
    return out


@njit(cache=True)
def expand_rows(
    rows: FloatArray,
    first: int,
    count: int,
    loiter_turn: float,
    grid: bool,
    speed: float,
    dt: float,
    cell: float,
) -> FloatArray:
    """`trajectory.expand` for every row."""
    out = np.empty((rows.shape[0], count + 1, 2))
    for i in range(rows.shape[0]):
        out[i] = expand(rows[i], first, count, loiter_turn, grid, speed, dt, cell)
    return out


@njit(cache=True)
def expand_with_centres(
    rows: FloatArray, first: int, count: int, kinematics: tuple[float, bool, float, float, float]
) -> tuple[FloatArray, FloatArray]:
    """`expand_rows` from step `first`, with the loiter centres of the rows.

    `expand_rows` from step `first` (count + 1 points) and the loiter centres of the rows
    (`loiter_centre`: the loiter begins after a row's M planned turns, at index start + M - first)."""
    pts = expand_rows(rows, first, count, *kinematics)
    horizon = rows.shape[1] - HEAD
    starts = np.empty(rows.shape[0], dtype=np.int64)
    for r in range(rows.shape[0]):
        starts[r] = int(rows[r, 0]) + horizon - first
    return pts, loiter_centres(pts, starts)
