"""Receding horizon predictive control (eqs. 22-25, 29): score the enumerated paths and pick one.

The scoring loops run compiled (numba): they are the hot path of every agent step.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from companion.core.geometry import FloatArray, IntArray
from companion.core.potential import link_cost, safety_cost

PENALTY_KNEE = 10.0


@njit(cache=True)
def soft_exp(x: float) -> float:
    """exp(x) up to x = PENALTY_KNEE, then continued linearly with the same slope.

    Keeps the region penalty of eq. 25 increasing, with a useful gradient, far from V* while
    staying far below the connectivity and safety barriers (see potential.EXPONENT_CAP).
    """
    if x <= PENALTY_KNEE:
        return math.exp(x)
    return math.exp(PENALTY_KNEE) * (1.0 + x - PENALTY_KNEE)


@njit(cache=True)
def search_benefit(
    points: FloatArray,
    fov: IntArray,
    values_padded: FloatArray,
    delta1: float,
    point_labels: IntArray,
    task: int,
    generator: FloatArray,
    circumradius: float,
    delta2: float,
) -> FloatArray:
    """Eq. 25: J^A = delta_1 sum_m sum_{p in C(w_m)} v_p - sum_m delta2bar exp(||w_m - q*|| / R*).

    `fov` (n_l, M, K) holds the FOV cells of each path point (eq. 3), padded with an index whose
    entry of `values_padded` is 0; v is eta (proposed, pheromone) or s (no task assignment).
    delta2bar is 0 where the point's cell label is `task` (inside V*) and delta_2 elsewhere;
    `task` < 0 means no assigned region, hence no penalty. exp is `soft_exp` (linear past e^10).
    """
    n_paths, horizon, n_fov = fov.shape
    out = np.zeros(n_paths)
    for i in range(n_paths):
        total = 0.0
        for m in range(horizon):
            for c in range(n_fov):
                total += values_padded[fov[i, m, c]]
        total *= delta1
        if task >= 0:
            for m in range(horizon):
                if point_labels[i, m] != task:
                    dx = points[i, m, 0] - generator[0]
                    dy = points[i, m, 1] - generator[1]
                    total -= delta2 * soft_exp(math.sqrt(dx * dx + dy * dy) / circumradius)
        out[i] = total
    return out


@njit(cache=True)
def path_expense(
    points: FloatArray,
    neighbour_tracks: FloatArray,
    reach: float,
    r_c: float,
    r_c_attr: float,
    r_s: float,
    r_s_rep: float,
) -> FloatArray:
    """Eq. 29: J^B = sum_m sum_{j in MST neighbours} F(d~_{j,m}) with F of eq. 28.

    `neighbour_tracks` (n_j, M + 1, 2) holds each MST neighbour's position at t_k and its predicted
    positions at t_{k+1..k+M}. Both UAVs replan every step, so a neighbour may leave its predicted
    track. The repulsion term at step m uses the smaller of the predicted distance and the worst
    case (the neighbour moved m * `reach` straight towards w(k+m|k)); the attraction term of the
    first step uses the larger of the predicted distance and the worst case (the neighbour moved
    `reach` straight away). So a path whose first step scores no barrier keeps every MST link
    within R_c and every MST neighbour beyond R_s at t_{k+1}, whatever the neighbour does.
    """
    n_paths, horizon = points.shape[0], points.shape[1]
    out = np.zeros(n_paths)
    for i in range(n_paths):
        total = 0.0
        for j in range(neighbour_tracks.shape[0]):
            for m in range(horizon):
                dx = points[i, m, 0] - neighbour_tracks[j, m + 1, 0]
                dy = points[i, m, 1] - neighbour_tracks[j, m + 1, 1]
                d = math.sqrt(dx * dx + dy * dy)
                nx = points[i, m, 0] - neighbour_tracks[j, 0, 0]
                ny = points[i, m, 1] - neighbour_tracks[j, 0, 1]
                from_now = math.sqrt(nx * nx + ny * ny)
                d_safe = min(d, from_now - (m + 1) * reach)
                d_link = max(d, from_now + reach) if m == 0 else d
                total += link_cost(d_link, r_c, r_c_attr) + safety_cost(d_safe, r_s, r_s_rep)
        out[i] = total
    return out


@njit(cache=True)
def grid_path_cells(
    points: FloatArray, x0: float, y0: float, size: float, lattice: IntArray, fov_table: IntArray
) -> tuple[IntArray, IntArray, IntArray]:
    """Grid mode: the cell under each path point (-1 outside), its FOV cells (eq. 3, a row of
    `fov_table`, whose last row is padding) and the number of leading points inside the region."""
    n_paths, horizon = points.shape[0], points.shape[1]
    ny, nx = lattice.shape
    cells = np.full((n_paths, horizon), -1, dtype=np.int64)
    fov = np.empty((n_paths, horizon, fov_table.shape[1]), dtype=np.int64)
    prefix = np.zeros(n_paths, dtype=np.int64)
    pad = fov_table.shape[0] - 1
    for i in range(n_paths):
        inside = True
        for m in range(horizon):
            col = math.floor((points[i, m, 0] - x0) / size + 0.5)
            row = math.floor((points[i, m, 1] - y0) / size + 0.5)
            if 0 <= col < nx and 0 <= row < ny:
                cells[i, m] = lattice[row, col]
            c = cells[i, m]
            fov[i, m, :] = fov_table[c if c >= 0 else pad]
            inside = inside and c >= 0
            if inside:
                prefix[i] += 1
    return cells, fov, prefix


@njit(cache=True)
def select_path(scores: FloatArray, prefix: IntArray) -> int:
    """Eq. 22: the best-scoring path among those that stay in the region longest (all M steps if any).

    Ties go to the first path in enumeration order (the straightest).
    """
    longest = prefix.max()
    best = -1
    for i in range(scores.shape[0]):
        if prefix[i] == longest and (best < 0 or scores[i] > scores[best]):
            best = i
    return best
