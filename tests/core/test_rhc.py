"""RHC (eqs. 22-25, 29): search benefit, path expense, path selection and path cells."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.core.geometry import ConvexPolygon, Grid
from companion.core.kinematics import Kinematics, PathTree
from companion.core.rhc import (
    grid_path_cells,
    path_expense,
    rank_candidates,
    rank_grid_candidates,
    rank_paths,
    region_key,
    search_benefit,
    soft_exp,
)
from companion.core.routes import STRAIGHT

# cells 0, 1, 2 with values 0.5, 1.0, 0.2; index 3 is the padding (value 0)
VALUES = np.array([0.5, 1.0, 0.2, 0.0])
POINTS = np.array([[[0.0, 0.0], [10.0, 0.0]], [[0.0, 0.0], [100.0, 0.0]]])
FOV = np.array([[[0, 1], [2, 3]], [[1, 3], [3, 3]]], dtype=np.int64)
GEN = np.array([0.0, 0.0])


def benefit(
    labels: list[list[int]], task: int, points: np.ndarray = POINTS, radius: float = 100.0
) -> np.ndarray:
    lab = np.array(labels, dtype=np.int64)
    return search_benefit(points, FOV, VALUES, 2.0, lab, task, GEN, radius, 0.5, STRAIGHT)


def test_search_benefit_sums_fov_values_without_penalty_inside_the_task() -> None:
    # delta_1 = 2: path 0 sees 0.5 + 1.0 + 0.2 + 0 = 1.7 -> 3.4; path 1 sees 1.0 -> 2.0
    assert benefit([[1, 1], [1, 1]], task=1) == pytest.approx([3.4, 2.0])


def test_search_benefit_penalises_points_outside_the_task() -> None:
    # path 1, step 2 at (100, 0) is in task 0, not task 1: delta_2 exp(||w - q*|| / R*) =
    # 0.5 * exp(100 / 100) = 1.3591409 -> 2.0 - 1.3591409 = 0.6408591
    assert benefit([[1, 1], [1, 0]], task=1) == pytest.approx([3.4, 0.6408591])
    # a point outside the region (label -1) is outside the task too
    assert benefit([[1, 1], [1, -1]], task=1) == pytest.approx([3.4, 0.6408591])
    # path 0, both points outside: 0.5 * (exp(0) + exp(0.1)) = 0.5 * (1 + 1.1051709) = 1.0525855
    assert benefit([[0, 0], [1, 1]], task=1)[0] == pytest.approx(3.4 - 1.0525855)


def test_no_task_means_no_penalty() -> None:
    assert benefit([[0, 0], [-1, -1]], task=-1) == pytest.approx([3.4, 2.0])


def test_soft_exp_is_exp_then_linear() -> None:
    assert soft_exp(1.0) == pytest.approx(math.e)
    assert soft_exp(10.0) == pytest.approx(22026.465795)
    # past the knee: e^10 * (1 + x - 10); x = 12 -> 22026.465795 * 3 = 66079.397385
    assert soft_exp(12.0) == pytest.approx(66079.397385)
    far = np.array([[[1200.0, 0.0], [0.0, 0.0]]])
    got = search_benefit(far, FOV[:1], VALUES, 2.0, np.array([[0, 1]]), 1, GEN, 100.0, 0.5, STRAIGHT)
    assert got[0] == pytest.approx(3.4 - 0.5 * 66079.397385)


COMMS = (1000.0, 700.0, 60.0, 120.0)  # R_c, R'_c, R_s, R'_s


def expense(points: list, track: list) -> float:
    """One path against one MST neighbour's predicted track (its anchor step, then one point a step)."""
    cost = path_expense(
        np.array([points], dtype=float), np.array([track], dtype=float), 1000.0, 700.0, 60.0, 120.0
    )
    return float(cost[0])


def test_path_expense_zero_in_the_band() -> None:
    # neighbour steady at 400 m: inside [R'_s, R'_c] = [120, 700]
    assert expense([[0, 0], [0, 0]], [[400, 0], [400, 0], [400, 0]]) == 0.0
    assert (
        path_expense(np.zeros((4, 3, 2)), np.zeros((0, 4, 2)), 1000.0, 700.0, 60.0, 120.0).tolist()
        == [0.0] * 4
    )


def test_path_expense_is_eq_29_on_the_predicted_distances() -> None:
    # step 1 at 150 m: (120 - 150) < 0 -> 0; step 2 at 100 m: (120 - 100) / (100 - 60) = 0.5 -> e^0.5 - 1
    assert expense([[0, 0], [0, 0]], [[0, 500], [0, 150], [0, 100]]) == pytest.approx(0.6487213)
    # attraction: 800 m -> (800 - 700) / (1000 - 800) = 0.5 -> e^0.5 - 1; the anchor point is not scored
    assert expense([[0, 0]], [[0, 50], [800, 0]]) == pytest.approx(0.6487213)
    # the path's own points move too: (0, 0) then (0, 40) against a neighbour steady at (0, 140):
    # 140 -> 0; 100 -> 0.5 -> e^0.5 - 1
    assert expense([[0, 0], [0, 40]], [[0, 140], [0, 140], [0, 140]]) == pytest.approx(0.6487213)


def test_path_expense_barriers_beyond_the_limits() -> None:
    # beyond R_c or inside R_s the barrier is above e^30 and grows with the violation
    assert expense([[0, 0]], [[0, 0], [1020, 0]]) >= math.expm1(30.0)
    assert expense([[0, 0]], [[0, 0], [40, 0]]) > expense([[0, 0]], [[0, 0], [50, 0]]) >= math.expm1(30.0)


def test_region_key_is_the_prefix_inside_and_the_distance_back_outside() -> None:
    square = ConvexPolygon.from_vertices([(0, 0), (100, 0), (100, 100), (0, 100)])
    pts = np.array([[[50, 50], [50, 90]], [[50, 140], [50, 180]]], dtype=float)
    key = region_key(np.array([2, 0]), pts, square.normals, square.offsets, 40.0)
    assert key[0] == 2.0 and key[1] < key[0]
    # both paths start outside: (40 + 80) / 40 = 3 cells beyond, and (10 + 50) / 40 = 1.5 cells
    outside = np.array([[[50, 140], [50, 180]], [[50, 110], [50, 150]]], dtype=float)
    key = region_key(np.array([0, 0]), outside, square.normals, square.offsets, 40.0)
    assert key.tolist() == pytest.approx([-3.0, -1.5])


def select(scores: list[float], prefix: list[int], allowed: list[int] | None = None) -> int:
    """The path the safety layer takes: the first in `rank_paths` order that it allows."""
    order = rank_paths(np.array(scores, dtype=float), np.array(prefix, dtype=float))
    assert sorted(order.tolist()) == list(range(len(scores)))
    return next((int(i) for i in order if allowed is None or allowed[i]), -1)


def test_paths_rank_by_the_longest_in_region_prefix_then_score() -> None:
    # paths 0, 2, 3 stay in for all 3 steps; among them path 2 scores best
    assert select([1.0, 5.0, 4.0, 3.0], [3, 2, 3, 3]) == 2
    assert rank_paths(np.array([1.0, 5.0, 4.0, 3.0]), np.array([3.0, 2.0, 3.0, 3.0])).tolist() == [2, 3, 0, 1]
    # a great score does not buy leaving the region earlier
    assert select([1.0, 100.0], [3, 2]) == 0
    # when none stays in for all steps, the longest prefix wins
    assert select([9.0, 1.0, 2.0], [0, 1, 1]) == 2


def test_the_first_path_the_safety_layer_allows() -> None:
    assert select([1.0, 5.0, 4.0], [3, 3, 3], [1, 0, 1]) == 2
    # the region prefix counts among the allowed paths only
    assert select([1.0, 9.0, 2.0], [3, 2, 3], [0, 1, 0]) == 1
    assert select([1.0, 9.0, 2.0], [3, 2, 3], [0, 0, 0]) == -1


def test_ties_go_to_the_first_path() -> None:
    assert select([2.0, 2.0, 2.0], [3, 3, 3]) == 0
    assert select([1.0, 2.0, 2.0], [3, 3, 3]) == 1
    assert rank_paths(np.array([2.0, 2.0, 2.0]), np.array([3.0, 3.0, 3.0])).tolist() == [0, 1, 2]


@pytest.fixture(scope="module")
def small_grid() -> Grid:
    # 3 x 3 cells of 40 m: centres 20, 60, 100 on each axis
    return Grid.build(ConvexPolygon.from_vertices([(0, 0), (120, 0), (120, 120), (0, 120)]), 40.0, 60.0)


def test_grid_path_cells(small_grid: Grid) -> None:
    g = small_grid
    pts = np.array(
        [
            [[20.0, 20.0], [60.0, 20.0], [100.0, 20.0]],  # all inside
            [[20.0, 20.0], [140.0, 20.0], [100.0, 20.0]],  # leaves at step 2: prefix 1
            [[-20.0, 20.0], [20.0, 20.0], [60.0, 20.0]],  # starts outside: prefix 0
        ]
    )
    cells, fov, prefix = grid_path_cells(pts, g.x0, g.y0, g.cell_size, g.lattice, g.fov_table)
    assert prefix.tolist() == [3, 1, 0]
    assert cells.tolist() == [[0, 1, 2], [0, -1, 2], [-1, 0, 1]]
    assert np.array_equal(fov[0, 0], g.fov_table[0])
    assert np.all(fov[1, 1] == g.n_cells)  # outside: all padding
    # FOV of the corner cell (20, 20): the 2 x 2 block 0, 1, 3, 4
    assert sorted(c for c in fov[0, 0].tolist() if c < g.n_cells) == [0, 1, 3, 4]


@pytest.fixture(scope="module")
def scenario_grid() -> Grid:
    square = [(-1000.0, -1000.0), (1000.0, -1000.0), (1000.0, 1000.0), (-1000.0, 1000.0)]
    return Grid.build(ConvexPolygon.from_vertices(square), 40.0, 60.0)


@settings(max_examples=50, deadline=None)
@given(st.integers(0, 49), st.integers(0, 49), st.integers(0, 7), st.integers(0, 2**32 - 1))
def test_chosen_path_stays_in_the_region(scenario_grid: Grid, col: int, row: int, h8: int, seed: int) -> None:
    g = scenario_grid
    tree = PathTree.build(Kinematics("grid", 20.0, 2.0, math.pi / 4, 40.0), 3)
    x, y = -980.0 + 40 * col, -980.0 + 40 * row
    pts = tree.expand(x, y, h8 * math.pi / 4)
    _, _, prefix = grid_path_cells(pts, g.x0, g.y0, g.cell_size, g.lattice, g.fov_table)
    inside = np.asarray(g.region.contains(pts[..., 0], pts[..., 1]))
    assert np.array_equal(prefix, np.cumprod(inside, axis=1).sum(axis=1))
    scores = np.random.default_rng(seed).normal(size=len(pts))
    best = int(rank_paths(scores, prefix.astype(float))[0])
    assert prefix[best] == prefix.max()
    if prefix.max() == 3:
        assert inside[best].all()


@settings(max_examples=40, deadline=None)
@given(
    st.integers(-2, 51), st.integers(-2, 51), st.integers(0, 7), st.integers(-1, 9), st.integers(0, 2**32 - 1)
)
def test_grid_path_ranking_in_one_call_matches_its_parts(
    scenario_grid: Grid, col: int, row: int, h8: int, task: int, seed: int
) -> None:
    """`rank_grid_candidates` = `PathTree.expand` + `grid_path_cells` + the task labels +
    `rank_candidates`,
    from anywhere on or just off the grid, with or without a task and a neighbour."""
    g = scenario_grid
    rng = np.random.default_rng(seed)
    tree = PathTree.build(Kinematics("grid", 20.0, 2.0, math.pi / 4, 40.0), 3)
    x, y, heading = -980.0 + 40 * col, -980.0 + 40 * row, h8 * math.pi / 4
    values = np.append(rng.random(g.n_cells), 0.0)
    cell_labels = np.append(rng.integers(0, 10, g.n_cells), -1)
    n_nbrs = int(rng.integers(0, 3))
    tracks = np.array([x, y]) + rng.normal(0, 150, (n_nbrs, 4, 2))
    region = (task, np.array([x + 100.0, y - 50.0]), 200.0, STRAIGHT)
    comms = (500.0, 400.0, 60.0, 100.0)
    weights = ((1.0, 0.5), (1.0, 0.01), comms, g.region.normals, g.region.offsets, g.cell_size)
    cells_of = (g.x0, g.y0, g.lattice, g.fov_table)
    order, path_points = rank_grid_candidates(
        x, y, tree.offsets_from(heading), cells_of, values, cell_labels, region, tracks, weights
    )
    pts = tree.expand(x, y, heading)
    cells, fov, prefix = grid_path_cells(pts, g.x0, g.y0, g.cell_size, g.lattice, g.fov_table)
    labels = np.where(cells >= 0, cell_labels[cells], -1)
    assert np.array_equal(order, rank_candidates(pts, fov, prefix, values, labels, region, tracks, weights))
    assert np.array_equal(path_points, pts)
