"""Flight distances around the keep-out: d_ij of eq. 16 and ||w_m - q*|| of eq. 25 as routes.

In a convex region without no-fly zones both are straight-line distances, as in the paper. Where
the keep-out (`search_area.keepout_pieces`) stands between a UAV and a task's generator the
straight line would pull the UAV into it, so both read instead the shortest route on the grid's
lattice (8-neighbour moves, Dijkstra) from the generator to the lattice node nearest the point,
plus the point's offset from that node (docs/algorithm.md, "No-fly zones").
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from companion.core.geometry import BoolArray, FloatArray, Grid
from companion.core.search_area import clear_of

# (field (n_tasks, ny * nx), or (0, 0) for straight lines; lattice x0, y0, cell size, nx, ny)
RouteTable = tuple[FloatArray, float, float, float, int, int]
STRAIGHT: RouteTable = (np.zeros((0, 0)), 0.0, 0.0, 1.0, 0, 0)
MOVES = ((1, 0), (-1, 0), (0, 1), (0, -1), (1, 1), (1, -1), (-1, 1), (-1, -1))


def open_nodes(grid: Grid, normals: FloatArray, offsets: FloatArray, keepout: FloatArray) -> BoolArray:
    """Which lattice nodes (ny, nx) a path may pass: inside the fence and clear of the keep-out."""
    cell = grid.cell_size
    cx, cy = np.meshgrid(grid.x0 + cell * np.arange(grid.nx), grid.y0 + cell * np.arange(grid.ny))
    pts = np.column_stack([cx.ravel(), cy.ravel()])
    inside = np.all(pts @ normals.T <= offsets, axis=1)
    clear = np.array([inside[i] and clear_of(pts[i : i + 1], keepout) for i in range(len(pts))], dtype=bool)
    return clear.reshape(grid.ny, grid.nx)


def route_table(grid: Grid, generators: FloatArray, open_: BoolArray) -> RouteTable:
    """Each generator's route distance to every lattice node, around the closed nodes.

    Moves leave open nodes only, so a closed node is reached from its open neighbours (a path's
    point just inside the keep-out reads a distance a step longer than its neighbour's) and a node
    deep inside reads the longest route plus its straight distance, never less than around.
    """
    ny, nx, cell = grid.ny, grid.nx, grid.cell_size
    rows, cols, weights = [], [], []
    index = np.arange(ny * nx).reshape(ny, nx)
    for dx, dy in MOVES:
        src = index[max(0, -dy) : ny - max(0, dy), max(0, -dx) : nx - max(0, dx)]
        dst = index[max(0, dy) : ny - max(0, -dy), max(0, dx) : nx - max(0, -dx)]
        keep = open_.ravel()[src.ravel()]
        rows.append(src.ravel()[keep])
        cols.append(dst.ravel()[keep])
        weights.append(np.full(int(keep.sum()), cell * math.hypot(dx, dy)))
    graph = coo_matrix(
        (np.concatenate(weights), (np.concatenate(rows), np.concatenate(cols))), shape=(ny * nx, ny * nx)
    ).tocsr()
    col = np.clip(np.rint((generators[:, 0] - grid.x0) / cell).astype(np.int64), 0, nx - 1)
    row = np.clip(np.rint((generators[:, 1] - grid.y0) / cell).astype(np.int64), 0, ny - 1)
    field = np.atleast_2d(dijkstra(graph, directed=True, indices=row * nx + col))
    node_x = np.tile(grid.x0 + cell * np.arange(nx), ny)
    node_y = np.repeat(grid.y0 + cell * np.arange(ny), nx)
    for j in range(field.shape[0]):
        far = ~np.isfinite(field[j])
        if far.any():
            straight = np.hypot(node_x[far] - generators[j, 0], node_y[far] - generators[j, 1])
            field[j, far] = np.max(field[j, ~far], initial=0.0) + straight
    return (np.ascontiguousarray(field), grid.x0, grid.y0, cell, nx, ny)


@njit(cache=True)
def route_distance(routes: RouteTable, task: int, x: float, y: float, gx: float, gy: float) -> float:
    """How far (x, y) is from task `task`'s generator (gx, gy): by route, else in a straight line.

    Straight when the table is empty (a convex region without zones) or the point lies off the
    lattice (beyond the region's bounding box, in the margin)."""
    field, x0, y0, cell, nx, ny = routes
    if field.shape[0] > 0:
        col = int(np.rint((x - x0) / cell))
        row = int(np.rint((y - y0) / cell))
        if 0 <= col < nx and 0 <= row < ny:
            return field[task, row * nx + col] + math.hypot(x - (x0 + col * cell), y - (y0 + row * cell))
    return math.hypot(x - gx, y - gy)
