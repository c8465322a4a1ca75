"""Receding horizon predictive control (eqs. 22-25, 29): score the enumerated paths and pick one.

The scoring loops run compiled (numba): they are the hot path of every agent step.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from companion.core.geometry import FloatArray, Grid, IntArray
from companion.core.kinematics import Kinematics
from companion.core.potential import link_cost, safety_cost
from companion.core.routes import RouteTable, route_distance

PENALTY_KNEE = 10.0
BAND_MARGIN = 1e-9  # relative: a squared distance this far inside eq. 28's band is in it


# Plain tuples (numba types them in C, a NamedTuple costs about a microsecond a call):
# the UAV's assigned region V* of eq. 25: its task (-1: none, hence no penalty), generator q* and
# circumradius R*, and the routes to the generators (`routes.RouteTable`)
TaskRegion = tuple[int, FloatArray, float, RouteTable]
# eq. 22's constants: (delta_1, delta_2) of eq. 25, (chi_1, chi_2) of eq. 22, (R_c, R'_c, R_s,
# R'_s) of eq. 28, the region's half-planes (normals, offsets) and the cell size (`region_key`)
ScoreWeights = tuple[
    tuple[float, float], tuple[float, float], tuple[float, float, float, float], FloatArray, FloatArray, float
]
# grid mode's cell lookup (`grid_path_cells`): the lattice's origin x0, y0, the cell of each lattice
# node (-1 outside) and each cell's FOV cells (eq. 3; the last row is padding)
GridCells = tuple[float, float, IntArray, IntArray]


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
    routes: RouteTable,
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
            total = _penalised(total, points, point_labels, i, task, generator, circumradius, delta2, routes)
        out[i] = total
    return out


@njit(cache=True)
def _penalised(
    total: float,
    points: FloatArray,
    point_labels: IntArray,
    i: int,
    task: int,
    generator: FloatArray,
    circumradius: float,
    delta2: float,
    routes: RouteTable,
) -> float:
    """`total` less eq. 25's penalty of path i's points outside task `task`, one point at a time."""
    for m in range(points.shape[1]):
        if point_labels[i, m] != task:
            x, y = points[i, m, 0], points[i, m, 1]
            d = route_distance(routes, task, x, y, generator[0], generator[1])
            total -= delta2 * soft_exp(d / circumradius)
    return total


@njit(cache=True)
def path_expense(
    points: FloatArray, neighbour_tracks: FloatArray, r_c: float, r_c_attr: float, r_s: float, r_s_rep: float
) -> FloatArray:
    """Eq. 29: J^B, the virtual force's cost of each path against the MST neighbours.

    Eq. 29: J^B = sum_m sum_{j in MST neighbours} F(d~_{j,m}) with F of eq. 28 and d~_{j,m} the
    distance from path point m to neighbour j's predicted position at the same step.

    `neighbour_tracks` (n_j, M + 1, 2) holds each MST neighbour's predicted positions at the path's
    anchor step and at the M steps of the path. (Separation and links are guaranteed by the safety
    layer, core.commitment; this soft term only shapes the search, as in the paper.)
    """
    n_paths, horizon = points.shape[0], points.shape[1]
    out = np.zeros(n_paths)
    # well inside the band by the squared distance (a margin far above its rounding): no hypot
    band = r_s < r_s_rep <= r_c_attr < r_c and r_s_rep > 0.0
    inner, outer = (r_s_rep * (1.0 + BAND_MARGIN)) ** 2, (r_c_attr * (1.0 - BAND_MARGIN)) ** 2
    for j in range(neighbour_tracks.shape[0]):
        for i in range(n_paths):
            for m in range(horizon):
                dx = points[i, m, 0] - neighbour_tracks[j, m + 1, 0]
                dy = points[i, m, 1] - neighbour_tracks[j, m + 1, 1]
                if band and inner <= dx * dx + dy * dy <= outer:
                    continue
                d = math.hypot(dx, dy)
                if r_s < r_s_rep <= d <= r_c_attr < r_c:
                    continue  # in the band both terms are expm1(0) = 0: adding them changes nothing
                out[i] += link_cost(d, r_c, r_c_attr) + safety_cost(d, r_s, r_s_rep)
    return out


@njit(cache=True)
def grid_path_cells(
    points: FloatArray, x0: float, y0: float, size: float, lattice: IntArray, fov_table: IntArray
) -> tuple[IntArray, IntArray, IntArray]:
    """Grid mode: each path point's cell and FOV cells (eq. 3), and the in-region prefix.

    Grid mode: the cell under each path point (-1 outside), its FOV cells (eq. 3, a row of
    `fov_table`, whose last row is padding) and the number of leading points inside the region."""
    cells, prefix = _lattice_cells(points, x0, y0, size, lattice)
    fov = np.empty((cells.shape[0], cells.shape[1], fov_table.shape[1]), dtype=np.int64)
    pad = fov_table.shape[0] - 1
    for i in range(cells.shape[0]):
        for m in range(cells.shape[1]):
            c = cells[i, m]
            fov[i, m, :] = fov_table[c if c >= 0 else pad]
    return cells, fov, prefix


@njit(cache=True)
def _lattice_cells(
    points: FloatArray, x0: float, y0: float, size: float, lattice: IntArray
) -> tuple[IntArray, IntArray]:
    """Grid mode: the cell under each path point (-1 outside) and each path's in-region prefix."""
    n_paths, horizon = points.shape[0], points.shape[1]
    ny, nx = lattice.shape
    cells = np.full((n_paths, horizon), -1, dtype=np.int64)
    prefix = np.zeros(n_paths, dtype=np.int64)
    for i in range(n_paths):
        inside = True
        for m in range(horizon):
            col = math.floor((points[i, m, 0] - x0) / size + 0.5)
            row = math.floor((points[i, m, 1] - y0) / size + 0.5)
            if 0 <= col < nx and 0 <= row < ny:
                cells[i, m] = lattice[row, col]
            inside = inside and cells[i, m] >= 0
            if inside:
                prefix[i] += 1
    return cells, prefix


def continuous_path_cells(
    grid: Grid, kin: Kinematics, pts: FloatArray
) -> tuple[IntArray, IntArray, IntArray]:
    """Continuous mode: each path point's cell and FOV cells (eq. 3), and the in-region prefix.

    Continuous mode: the cell under each path point, the FOV cells of each point (eq. 3), and
    the in-region prefix (grid mode does all this inside `rank_grid_candidates`).

    A path's last point must also leave room to turn back (a turning diameter from the
    boundary), else the path counts one point short: three steps of eq. 2 cannot see the
    U-turn a corner needs.
    """
    cells = grid.cell_at(pts)
    depth = -np.max(pts @ grid.region.normals.T - grid.region.offsets, axis=-1)  # metres inside
    prefix = np.cumprod(depth >= 0, axis=1).sum(axis=1)
    diameter = 2 * kin.speed * kin.dt / kin.turn_limit
    prefix -= (prefix == pts.shape[1]) & (depth[:, -1] < diameter)
    return cells, grid.fov_cells(pts), prefix


@njit(cache=True)
def region_key(
    prefix: IntArray, points: FloatArray, normals: FloatArray, offsets: FloatArray, cell_size: float
) -> FloatArray:
    """How well each path keeps to the region (the region constraint of eq. 23).

    How well each path keeps to the region (the region constraint of eq. 23): its in-region prefix
    (M when it never leaves), and for a path whose first point is outside, minus the distance its
    points lie beyond the boundary (summed, in cells), so that a UAV outside turns back at once."""
    if prefix.max() > 0:  # paths that leave at once cannot compete with one that does not
        return prefix.astype(np.float64)
    n_paths, horizon = points.shape[0], points.shape[1]
    out = np.zeros(n_paths)
    for i in range(n_paths):
        for m in range(horizon):
            beyond = -np.inf
            for e in range(normals.shape[0]):
                d = points[i, m, 0] * normals[e, 0] + points[i, m, 1] * normals[e, 1] - offsets[e]
                beyond = max(beyond, d)
            out[i] -= max(beyond, 0.0) / cell_size
    return out


@njit(cache=True)
def rank_paths(scores: FloatArray, region: FloatArray) -> IntArray:
    """Eq. 22's order of preference: by region key, then score, then index.

    Eq. 22's order of preference: paths by `region_key` (all M steps in the region first), then
    by score, then by index (the straightest first). The safety layer takes the first path of this
    order that it allows (`Commitments.first_allowed`)."""
    by_score = np.argsort(-scores, kind="mergesort")
    for i in range(1, region.shape[0]):
        if region[i] != region[0]:  # (a NaN too)
            return by_score[np.argsort(-region[by_score], kind="mergesort")]
    return by_score  # one region key (every path inside, as a rule): the stable sort keeps the order


@njit(cache=True)
def rank_candidates(
    points: FloatArray,
    fov: IntArray,
    prefix: IntArray,
    values_padded: FloatArray,
    point_labels: IntArray,
    region: TaskRegion,
    neighbour_tracks: FloatArray,
    weights: ScoreWeights,
) -> IntArray:
    """Eq. 22: the paths in order of chi_1 J^A - chi_2 J^B (eqs. 25, 29), region first.

    Eq. 22: the paths in order of chi_1 J^A - chi_2 J^B (eqs. 25, 29), region first
    (`region_key`, `rank_paths`)."""
    delta = weights[0]
    task, generator, circumradius, routes = region
    benefit = search_benefit(
        points, fov, values_padded, delta[0], point_labels, task, generator, circumradius, delta[1], routes
    )
    return _ranked(points, prefix, benefit, neighbour_tracks, weights)


@njit(cache=True)
def _ranked(
    points: FloatArray,
    prefix: IntArray,
    benefit: FloatArray,
    neighbour_tracks: FloatArray,
    weights: ScoreWeights,
) -> IntArray:
    """Eq. 22's order of the paths given their eq. 25 benefit: chi_1 J^A - chi_2 J^B, region first."""
    _, chi, comms, normals, offsets, cell_size = weights
    expense = path_expense(points, neighbour_tracks, comms[0], comms[1], comms[2], comms[3])
    region_keys = region_key(prefix, points, normals, offsets, cell_size)
    return rank_paths(chi[0] * benefit - chi[1] * expense, region_keys)


@njit(cache=True)
def rank_grid_candidates(
    x: float,
    y: float,
    offsets: FloatArray,
    cells_of: GridCells,
    values_padded: FloatArray,
    cell_labels: IntArray,
    region: TaskRegion,
    neighbour_tracks: FloatArray,
    weights: ScoreWeights,
) -> tuple[IntArray, FloatArray]:
    """Grid mode's eq. 22 in one call: the paths of eq. 23 from (x, y), ranked.

    Grid mode in one call: the paths of eq. 23 from (x, y) (`offsets` is the `PathTree` table of
    the UAV's heading), their cells and FOVs (`grid_path_cells`, the FOVs read in place from the
    table), and `rank_candidates`. The task of each path point is read from `cell_labels` (-1
    outside the region). Returns the paths' order and their points."""
    pts = np.empty(offsets.shape)
    for i in range(offsets.shape[0]):
        for m in range(offsets.shape[1]):
            pts[i, m, 0], pts[i, m, 1] = offsets[i, m, 0] + x, offsets[i, m, 1] + y
    x0, y0, lattice, fov_table = cells_of
    cells, prefix = _lattice_cells(pts, x0, y0, weights[5], lattice)
    task, generator, circumradius, routes = region
    delta1, delta2 = weights[0]
    pad = fov_table.shape[0] - 1
    point_labels = cells  # read only inside a task's region
    if task >= 0:
        point_labels = np.full(cells.shape, -1, dtype=np.int64)
        for i in range(cells.shape[0]):
            for m in range(cells.shape[1]):
                if cells[i, m] >= 0:
                    point_labels[i, m] = cell_labels[cells[i, m]]
    benefit = np.zeros(cells.shape[0])
    for i in range(cells.shape[0]):
        total = 0.0  # search_benefit's sum, read straight from the FOV table
        for m in range(cells.shape[1]):
            row = cells[i, m] if cells[i, m] >= 0 else pad
            for c in range(fov_table.shape[1]):
                total += values_padded[fov_table[row, c]]
        total *= delta1
        if task >= 0:
            total = _penalised(total, pts, point_labels, i, task, generator, circumradius, delta2, routes)
        benefit[i] = total
    return _ranked(pts, prefix, benefit, neighbour_tracks, weights), pts
