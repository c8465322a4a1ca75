"""Eqs. 4-7 (weighted Laplacian, lambda_2) and the Kruskal MST of eq. 26."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from scipy.sparse.csgraph import connected_components, minimum_spanning_tree

from companion.core.connectivity import (
    algebraic_connectivity,
    kruskal_mst,
    laplacian,
    mst_neighbours,
    pairwise_distances,
    weighted_adjacency,
)

R_C = 1000.0


def test_laplacian_of_a_chain_of_three() -> None:
    # UAVs at x = 0, 600, 1200: d01 = d12 = 600 (linked), d02 = 1200 > R_c (no link).
    # w = exp(-600/1000)^3 = exp(-1.8) = 0.16529889
    # L = [[w, -w, 0], [-w, 2w, -w], [0, -w, w]]: eigenvalues 0, w, 3w -> lambda_2 = w.
    pos = np.array([[0.0, 0.0], [600.0, 0.0], [1200.0, 0.0]])
    w = 0.16529889
    expected = np.array([[w, -w, 0.0], [-w, 2 * w, -w], [0.0, -w, w]])
    assert np.allclose(laplacian(pos, R_C), expected, atol=1e-8)
    assert algebraic_connectivity(pos, R_C) == pytest.approx(w, rel=1e-7)


def test_lambda2_of_a_3_4_5_triangle() -> None:
    # d01 = 300, d02 = 400, d12 = 500: a = exp(-0.9) = 0.40656966, b = exp(-1.2) = 0.30119421,
    # c = exp(-1.5) = 0.22313016. For a weighted triangle the non-zero eigenvalues are
    # s -+ sqrt(a^2 + b^2 + c^2 - ab - bc - ca), s = a + b + c = 0.93089403:
    # sqrt(0.30580391 - 0.28037989) = 0.15944910 -> lambda_2 = 0.77144493, lambda_3 = 1.09034313.
    pos = np.array([[0.0, 0.0], [300.0, 0.0], [0.0, 400.0]])
    a = weighted_adjacency(pos, R_C)
    assert a[0, 1] == pytest.approx(0.40656966) and a[0, 2] == pytest.approx(0.30119421)
    assert a[1, 2] == pytest.approx(0.22313016) and np.allclose(a, a.T) and np.all(np.diag(a) == 0)
    assert algebraic_connectivity(pos, R_C) == pytest.approx(0.77144493, rel=1e-7)
    assert np.linalg.eigvalsh(laplacian(pos, R_C))[2] == pytest.approx(1.09034313, rel=1e-7)


def test_weight_is_zero_beyond_range_and_lambda2_zero_when_split() -> None:
    # Fourth UAV 1500 m from the nearest other one: no link at all, lambda_2 = 0.
    pos = np.array([[0.0, 0.0], [300.0, 0.0], [0.0, 400.0], [1800.0, 0.0]])
    a = weighted_adjacency(pos, R_C)
    assert np.all(a[3] == 0.0) and np.all(a[:, 3] == 0.0)
    assert algebraic_connectivity(pos, R_C) == 0.0  # exactly: the solver's +-1e-17 is clamped
    assert np.allclose(laplacian(pos, R_C).sum(axis=1), 0.0)


def test_kruskal_on_a_hand_example() -> None:
    # 0 (0,0), 1 (3,0), 2 (3,4), 3 (10,0): d01 = 3, d12 = 4, d02 = 5, d13 = 7, d23 = 8.06, d03 = 10.
    # Kruskal: take 01 (3), 12 (4), skip 02 (cycle), take 13 (7): total 14.
    pos = np.array([[0.0, 0.0], [3.0, 0.0], [3.0, 4.0], [10.0, 0.0]])
    edges = kruskal_mst(pos)
    assert sorted(map(tuple, edges.tolist())) == [(0, 1), (1, 2), (1, 3)]
    assert mst_neighbours(edges, 1).tolist() == [0, 2, 3]
    assert mst_neighbours(edges, 3).tolist() == [1]


def test_kruskal_ties_by_pair_order() -> None:
    # Unit square 0 (0,0), 1 (1,0), 2 (0,1), 3 (1,1): four sides of length 1 in order 01, 02, 13, 23;
    # 01, 02, 13 are taken and 23 would close the cycle 2-0-1-3.
    pos = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
    assert kruskal_mst(pos).tolist() == [[0, 1], [0, 2], [1, 3]]


def test_kruskal_degenerate_sizes() -> None:
    assert kruskal_mst(np.zeros((1, 2))).shape == (0, 2)
    assert kruskal_mst(np.array([[0.0, 0.0], [5.0, 0.0]])).tolist() == [[0, 1]]
    assert algebraic_connectivity(np.zeros((1, 2)), R_C) == 0.0


points = st.lists(st.tuples(st.floats(0, 3000), st.floats(0, 3000)), min_size=2, max_size=10)


@settings(max_examples=50, deadline=None)
@given(points)
def test_mst_spans_with_n_minus_1_edges_and_minimal_length(pts: list) -> None:
    pos = np.array(pts)
    d = pairwise_distances(pos)
    n = len(pos)
    assume(d[~np.eye(n, dtype=bool)].min() > 1e-3)  # scipy treats a 0 weight as no edge
    edges = kruskal_mst(pos)
    assert edges.shape == (n - 1, 2)
    assert np.all(edges[:, 0] < edges[:, 1])
    tree = np.zeros((n, n))
    tree[edges[:, 0], edges[:, 1]] = 1.0
    assert connected_components(tree, directed=False)[0] == 1  # spans every node
    total = d[edges[:, 0], edges[:, 1]].sum()
    assert total == pytest.approx(minimum_spanning_tree(d).sum(), rel=1e-9)


@settings(max_examples=50, deadline=None)
@given(points)
def test_lambda2_positive_iff_range_graph_connected(pts: list) -> None:
    pos = np.array(pts)
    d = pairwise_distances(pos)
    assume(np.all(np.abs(d - R_C) > 1e-6))  # no pair exactly at the range
    connected = connected_components(d <= R_C, directed=False)[0] == 1
    lam = algebraic_connectivity(pos, R_C)
    assert (lam > 0) == connected  # exactly zero when split (pass criteria test lambda_2 > 0)
    assert lam >= 0
