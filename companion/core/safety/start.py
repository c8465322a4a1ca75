"""The start: a tree of tethers and a contingency for every UAV, and the margin that allows one."""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from companion.core.geometry import FloatArray
from companion.core.kinematics import Kinematics
from companion.core.safety.limits import TURN_SIDES, Limits
from companion.core.safety.separation import compatible, inside_fence
from companion.core.search_area import spokes_clear
from companion.core.trajectory import HEAD, Reach, Trajectory, expand


def tether_tree(positions: FloatArray, link: float) -> tuple[tuple[int, ...], tuple[int, ...]]:
    """Ranks and parents of the tree of links that must hold in the start layout.

    Ranks and parents of the start layout: ranks in breadth-first order from UAV 0 over the graph
    of pairs closer than `link` (nearer neighbours first), each UAV's parent the nearest UAV of a
    lower rank within `link`, -1 for the root. A layout that is not connected gives a forest: each
    further component is ranked from its lowest id, whose parent is -1 too."""
    n = len(positions)
    d = np.linalg.norm(positions[:, None, :] - positions[None, :, :], axis=-1)
    rank = [-1] * n
    order: list[int] = []
    for root in range(n):
        if rank[root] >= 0:
            continue
        rank[root] = len(order)
        order.append(root)
        queue = deque([root])
        while queue:
            u = queue.popleft()
            for v in sorted(range(n), key=lambda v: d[u, v]):
                if rank[v] < 0 and d[u, v] < link:
                    rank[v] = len(order)
                    order.append(v)
                    queue.append(v)

    def parent(v: int) -> int:
        """The nearest UAV of a lower rank within `link` of v, -1 for none."""
        lower = [u for u in range(n) if rank[u] < rank[v] and d[u, v] < link]
        return min(lower, key=lambda u: d[u, v]) if lower else -1

    return tuple(rank), tuple(parent(v) for v in range(n))


def initial_trajectories(
    poses: FloatArray, parents: tuple[int, ...], ranks: tuple[int, ...], limits: Limits
) -> list[Trajectory]:
    """A start contingency per UAV, pairwise compatible and keeping every tether.

    A contingency per UAV from its start pose, pairwise compatible and keeping every tether to a
    parent: straight for s steps (0 <= s <= M, shorter first), then loiter on one side. Searched in
    rank order with backtracking; raises ValueError when the start layout admits none."""
    n, m = len(poses), limits.horizon
    turn = limits.reach.loiter_turn
    options: list[list[tuple[Trajectory, FloatArray]]] = []
    for x, y, h in poses:
        opts = []
        for s in range(m + 1):
            for side in TURN_SIDES:
                traj = Trajectory(
                    0, float(x), float(y), float(h), (0.0,) * s + (side * turn,) * (m - s), side
                )
                pts = limits.expand(limits.rows([traj]), 0)[0]
                if inside_fence(pts, limits.fence_normals, limits.fence_offsets, limits.keepout) and (
                    not limits.fan_keepout.shape[0]
                    or spokes_clear(pts, s, *limits.loiter_circle(traj)[:2], limits.fan_keepout)
                ):
                    opts.append((traj, pts))
        options.append(opts)
    order = sorted(range(n), key=lambda u: ranks[u])
    chosen: dict[int, FloatArray] = {}
    picks: dict[int, Trajectory] = {}
    empty = np.zeros((0, limits.reach.window + 1, 2))
    no_disks = np.zeros((0, 3))

    def place(i: int) -> bool:
        """Place the UAVs from rank i on, backtracking; whether all fit."""
        if i == len(order):
            return True
        u = order[i]
        others = np.array([chosen[v] for v in chosen]) if chosen else empty
        tethers = np.array([chosen[parents[u]]]) if parents[u] >= 0 else empty
        for traj, pts in options[u]:
            ok = compatible(
                pts,
                others,
                no_disks,
                tethers,
                no_disks,
                limits.separation,
                limits.disk_separation,
                limits.link,
            )
            if ok:
                chosen[u], picks[u] = pts, traj
                if place(i + 1):
                    return True
                del chosen[u], picks[u]
        return False

    if not place(0):
        raise ValueError(
            "no start contingency: the vehicles cannot all loiter from their start poses inside the "
            "fence while keeping the safety distance and their links"
        )
    return [picks[u] for u in range(n)]


def minimum_margin(kin: Kinematics, horizon: int) -> float:
    """The smallest operating margin that leaves every edge UAV a contingency inside the fence.

    The smallest operating margin with which a UAV anywhere on the region's edge, with any
    heading, has a contingency inside the fence: the largest, over headings, of how far beyond the
    edge its best start contingency (straight for s <= M steps, then loiter) reaches. The edge is a
    straight line through the UAV with outward normal +y."""
    reach = Reach.of(kin, horizon)
    grid = kin.mode == "grid"
    headings = np.arange(8) * math.pi / 4 if grid else np.linspace(-math.pi, math.pi, 361)
    worst = 0.0
    for h in headings:
        best = math.inf
        for s in range(horizon + 1):
            for side in TURN_SIDES:
                row = np.full(HEAD + horizon, float(side) * reach.loiter_turn)
                row[:HEAD] = (0, 0.0, 0.0, h, side)
                row[HEAD : HEAD + s] = 0.0
                pts = expand(row, 0, reach.window, reach.loiter_turn, grid, kin.speed, kin.dt, kin.cell_size)
                best = min(best, float(pts[:, 1].max()))
        worst = max(worst, best)
    return worst + reach.sagitta
