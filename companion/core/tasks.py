"""Task evaluation (eqs. 13-18) and reevaluation (eqs. 20-21) of the mission planning system."""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from typing import NamedTuple

import numpy as np
from numba import njit

from companion.core.geometry import FloatArray, IntArray
from companion.core.potential import link_cost
from companion.core.routes import STRAIGHT, RouteTable, route_distance


class CostWeights(NamedTuple):
    """The weights and constants of the task costs (eqs. 16-18).

    beta_1, beta_2 (eq. 18), kappa (eq. 16), the FOV area S_A, the cell diagonal, R_c, R'_c and the
    exponent cap of eq. 17."""

    beta1: float
    beta2: float
    kappa: float
    fov_area: float
    diagonal: float
    r_c: float
    r_c_attr: float
    comm_cap: float


NEAR_MARGIN = 1e-9  # relative: a squared distance this far within R'_c is within it

# `CostWeights` as the kernels take them: a plain tuple (numba types it in C, a NamedTuple costs
# about a microsecond a call), or the NamedTuple itself
Weights = tuple[float, float, float, float, float, float, float, float]

# The tasks V_j a bidder bids for (eq. 15): each cell's task label, and each task's cell count,
# generator q_j and area S_j (`cvt.Tessellation`); a plain tuple, which numba types in C
# and the routes to each generator (`routes.RouteTable`)
TaskSet = tuple[IntArray, IntArray, FloatArray, FloatArray, RouteTable]


@njit(cache=True)
def time_cost(
    position: FloatArray,
    generators: FloatArray,
    areas: FloatArray,
    w: Weights,
    routes: RouteTable,
    first: int,
) -> FloatArray:
    """Eq. 16: C^t_ij = d_ij / sqrt(Dx^2 + Dy^2) + kappa * S_j / S_A (arrival + search).

    d_ij is the route distance (`route_distance`; straight without a keep-out); `generators` are
    the tasks first, first + 1, ..."""
    _, _, kappa, fov_area, diagonal, _, _, _ = w
    out = np.empty(generators.shape[0])
    for j in range(generators.shape[0]):
        d = route_distance(routes, first + j, position[0], position[1], generators[j, 0], generators[j, 1])
        out[j] = d / diagonal + kappa * areas[j] / fov_area
    return out


@njit(cache=True)
def communication_costs(
    neighbours: FloatArray, generators: FloatArray, w: Weights
) -> tuple[FloatArray, FloatArray]:
    """Eq. 17: C^c_ij, capped for the auction and uncapped for eq. 21.

    Eq. 17: C^c_ij = sum over MST neighbours l of (exp(max(0, (d_lj - R'_c)/(R_c - d_lj))) - 1),
    twice: with each neighbour's term capped at exp(comm_cap) - 1, for the auction (a task beyond
    R_c of a neighbour is expensive, not impossible, since the swarm moves as a whole and the RHC
    keeps the links), and uncapped, for eq. 21 (beyond R_c is prohibitive)."""
    _, _, _, _, _, r_c, r_c_attr, comm_cap = w
    capped = np.zeros(generators.shape[0])
    uncapped = np.zeros(generators.shape[0])
    limit = math.expm1(comm_cap)
    # well within R'_c by the squared distance (a margin far above its rounding): no hypot
    near = (r_c_attr * (1.0 - NEAR_MARGIN)) ** 2 if 0.0 < r_c_attr < r_c else -1.0
    for j in range(generators.shape[0]):
        for n in range(neighbours.shape[0]):
            dx, dy = generators[j, 0] - neighbours[n, 0], generators[j, 1] - neighbours[n, 1]
            if dx * dx + dy * dy <= near:
                continue
            d = math.hypot(dx, dy)
            if d <= r_c_attr < r_c:
                continue  # the term is expm1(+-0) = +-0: adding it changes neither sum
            term = link_cost(d, r_c, r_c_attr)
            capped[j] += min(term, limit)
            uncapped[j] += term
    return capped, uncapped


@njit(cache=True)
def task_costs(
    position: FloatArray,
    neighbours: FloatArray,
    generators: FloatArray,
    areas: FloatArray,
    w: Weights,
    routes: RouteTable,
    first: int,
) -> tuple[FloatArray, FloatArray]:
    """Eq. 18: C_ij = beta_1 C^t_ij + beta_2 C^c_ij, for the auction and for eq. 21.

    Eq. 18, C_ij = beta_1 C^t_ij + beta_2 C^c_ij, for the tasks given by their generators and areas:
    the auction's cost (eq. 15; eq. 17 capped) and C*_{i,k} of eq. 21 (eq. 17 uncapped, so a task
    whose generator is near or beyond R_c of an MST neighbour, keeping it threatens that link,
    costs more than any C_max)."""
    beta1, beta2 = w[0], w[1]
    time = beta1 * time_cost(position, generators, areas, w, routes, first)
    capped, uncapped = communication_costs(neighbours, generators, w)
    return time + beta2 * capped, time + beta2 * uncapped


@njit(cache=True)
def task_income(labels: IntArray, eta: FloatArray, prior: FloatArray, n: int) -> FloatArray:
    """Eq. 15's income of each task: eta * Pr summed over its cells, in cell order.

    The running sum of a run of cells with one label stays in a register (the sums, and their
    order of addition, are those of adding each cell's term to its task's total in turn)."""
    income = np.zeros(n)
    if labels.shape[0] == 0:
        return income
    task, total = labels[0], 0.0
    for c in range(labels.shape[0]):
        if labels[c] != task:
            income[task] = total
            task = labels[c]
            total = income[task]
        total += eta[c] * prior[c]
    income[task] = total
    return income


@njit(cache=True)
def bid_rewards(
    eta: FloatArray,
    prior: FloatArray,
    covered: IntArray,
    tasks: TaskSet,
    v_max: float,
    c_max: float,
    position: FloatArray,
    neighbours: FloatArray,
    w: Weights,
    held: int,
) -> FloatArray:
    """A bidder's rewards R_ij (eq. 15), filtered by eq. 21 and the task held.

    A bidder's rewards (eq. 15, importance eta * Pr summed over each task's cells in cell
    order), zero for tasks it could not keep (eq. 21: complete, its `covered` cells beyond v_max,
    or costing more than C_max) and, when it holds task `held` (>= 0), for tasks not worth more than
    that one; empty when every task is complete."""
    labels, cell_counts, generators, areas, routes = tasks
    n = generators.shape[0]
    done = np.empty(n, dtype=np.bool_)
    for j in range(n):
        done[j] = covered[j] > v_max * cell_counts[j] or cell_counts[j] == 0  # none to see (`onto_flyable`)
    if done.all():
        return np.empty(0)
    auction, holding = task_costs(position, neighbours, generators, areas, w, routes, 0)
    reward = task_income(labels, eta, prior, n) / auction
    out = np.empty(n)
    for j in range(n):
        worthless = done[j] or holding[j] > c_max or (held >= 0 and reward[j] <= reward[held])
        out[j] = 0.0 if worthless else reward[j]
    return out


def task_completion(covered_cells: int, task_cells: int) -> float:
    """Eq. 20 (read as intended): v_i = S^A_{i,k} / S*_i, the covered share of the task's area."""
    return covered_cells / task_cells if task_cells else 1.0


def keep_task(completion: float, cost: float, v_max: float, c_max: float) -> bool:
    """Eq. 21: the task is kept while v_i <= v_max and C*_{i,k} <= C_max."""
    return completion <= v_max and cost <= c_max and math.isfinite(cost)


MAX_CONFIRM_BIDS = 16  # confirmation tasks a bidder bids for at once, its best


def confirm_bids(
    cells: IntArray,
    posteriors: FloatArray,
    centres: FloatArray,
    position: FloatArray,
    neighbours: FloatArray,
    w: Weights,
    c_max: float,
) -> tuple[IntArray, FloatArray]:
    """Eq. 15 for the confirmation task of each candidate cell: R = P_p / C (eq. 18), best first.

    The task of confirming candidate cell p is one look at it: its income is the posterior P_p
    (the targets the look settles, in the units of eq. 15's eta Pr), its cost eq. 18 with q_j the
    cell's centre and S_j the FOV area S_A (one look of search). Zero where keeping it would cost
    more than C_max (eq. 21); at most MAX_CONFIRM_BIDS of them."""
    gens = centres[cells]
    areas = np.full(cells.shape[0], w[3])
    auction, holding = task_costs(position, neighbours, gens, areas, w, STRAIGHT, 0)
    rewards = np.where(holding <= c_max, posteriors / auction, 0.0)
    best = np.argsort(-rewards, kind="stable")[:MAX_CONFIRM_BIDS]
    return cells[best], rewards[best]


def auction_table(
    n_tasks: int, bids: Sequence[tuple[Sequence[float], Sequence[int], Sequence[float]]], held: Iterable[int]
) -> tuple[IntArray, FloatArray, np.ndarray]:
    """The local auction's tasks, bids and availability over CVT and confirmation tasks.

    Columns: the n_tasks CVT tasks, then the confirmation task n_tasks + p of every candidate cell
    p some bidder bid for, in cell order (a bidder that did not bid for one bids 0). Returns each
    column's task id, the table (a row per bidder, as `bids`) and which columns no one in `held`
    holds."""
    cells = sorted(set().union(*(b[1] for b in bids)))
    column = {n_tasks + c: n_tasks + i for i, c in enumerate(cells)}
    ids = np.arange(n_tasks + len(cells))
    table = np.zeros((len(bids), ids.shape[0]))
    table[:, :n_tasks] = [cvt for cvt, _, _ in bids]
    if cells:
        ids[n_tasks:] = n_tasks + np.array(cells, dtype=np.int64)
        for row, (_, confirm, rewards) in enumerate(bids):
            for c, r in zip(confirm, rewards, strict=True):
                table[row, column[n_tasks + c]] = r
    available = np.ones(ids.shape[0], dtype=bool)
    for t in held:
        if 0 <= t < n_tasks:
            available[t] = False
        elif t in column:
            available[column[t]] = False
    return ids, table, available
