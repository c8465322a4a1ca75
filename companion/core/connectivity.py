"""Communication graph (eqs. 4-7), algebraic connectivity, and the Kruskal MST (eq. 26)."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from companion.core.geometry import FloatArray


@njit(cache=True)
def pairwise_distances(positions: FloatArray) -> FloatArray:
    """||mu_i - mu_j|| for every pair."""
    n = positions.shape[0]
    out = np.empty((n, n))
    for i in range(n):
        for j in range(n):
            dx, dy = positions[i, 0] - positions[j, 0], positions[i, 1] - positions[j, 1]
            out[i, j] = math.sqrt(dx * dx + dy * dy)
    return out


CONNECTED_LAMBDA2 = 1e-12


@njit(cache=True)
def weighted_adjacency(positions: FloatArray, comm_range: float) -> FloatArray:
    """Eq. 5: A = [w_ij a_ij] with a_ij = 1 iff d_ij <= R_c and w_ij = exp(-d_ij / R_c)^3."""
    n = positions.shape[0]
    a = np.zeros((n, n))
    for i in range(n):
        for j in range(i + 1, n):
            d = math.hypot(positions[i, 0] - positions[j, 0], positions[i, 1] - positions[j, 1])
            if d <= comm_range:
                a[i, j] = a[j, i] = math.exp(-d / comm_range) ** 3
    return a


@njit(cache=True)
def laplacian(positions: FloatArray, comm_range: float) -> FloatArray:
    """Eqs. 4, 6, 7: L = D - A, D the diagonal degree matrix of the weighted adjacency."""
    a = weighted_adjacency(positions, comm_range)
    return np.diag(a.sum(axis=1)) - a


@njit(cache=True)
def algebraic_connectivity(positions: FloatArray, comm_range: float) -> float:
    """lambda_2(L): the second-smallest Laplacian eigenvalue; > 0 iff the range graph is connected.

    A disconnected graph's lambda_2 is 0, which the eigensolver returns as +-1e-17 or so: values
    below `CONNECTED_LAMBDA2` are returned as exactly 0. (Every edge within R_c weighs at least
    e^-3, so a connected swarm's lambda_2 is many orders of magnitude above it.)
    """
    if positions.shape[0] < 2:
        return 0.0
    lam = np.linalg.eigvalsh(laplacian(positions, comm_range))[1]
    return lam if lam >= CONNECTED_LAMBDA2 else 0.0


@njit(cache=True)
def min_pair_distance(positions: FloatArray) -> float:
    """min_{i != j} ||mu_i - mu_j||; infinite for fewer than two UAVs."""
    best = math.inf
    for i in range(positions.shape[0]):
        for j in range(i + 1, positions.shape[0]):
            best = min(best, math.hypot(positions[i, 0] - positions[j, 0], positions[i, 1] - positions[j, 1]))
    return best


@njit(cache=True)
def kruskal_mst(positions: FloatArray) -> np.ndarray:
    """Eq. 26: Kruskal's minimum spanning tree of the complete distance graph.

    Edges are taken by increasing length, ties broken by (i, j), so every UAV that knows the same
    positions builds the same tree. Returns the N - 1 edges as rows (i, j), i < j.
    """
    n = positions.shape[0]
    m = n * (n - 1) // 2
    ii = np.empty(m, dtype=np.int64)
    jj = np.empty(m, dtype=np.int64)
    dd = np.empty(m)
    e = 0
    for i in range(n):
        for j in range(i + 1, n):
            ii[e], jj[e] = i, j
            dd[e] = math.hypot(positions[i, 0] - positions[j, 0], positions[i, 1] - positions[j, 1])
            e += 1
    order = np.argsort(dd, kind="mergesort")  # stable: equal lengths keep (i, j) order
    parent = np.arange(n)
    edges = np.empty((max(n - 1, 0), 2), dtype=np.int64)
    taken = 0
    for e in order:
        a, b = ii[e], jj[e]
        while parent[a] != a:
            a = parent[a]
        while parent[b] != b:
            b = parent[b]
        if a != b:
            parent[a] = b
            edges[taken, 0], edges[taken, 1] = ii[e], jj[e]
            taken += 1
            if taken == n - 1:
                break
    return edges


@njit(cache=True)
def mst_neighbours(edges: np.ndarray, node: int) -> np.ndarray:
    """Ñ_i: the nodes joined to `node` by an MST edge, ascending."""
    found = np.empty(edges.shape[0], dtype=np.int64)
    n = 0
    for e in range(edges.shape[0]):
        if edges[e, 0] == node or edges[e, 1] == node:
            found[n] = edges[e, 1] if edges[e, 0] == node else edges[e, 0]
            n += 1
    return np.sort(found[:n])
