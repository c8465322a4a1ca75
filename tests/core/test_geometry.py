"""Region, grid and the FOV of eq. 3 against hand-counted cells."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from companion.core.geometry import ConvexPolygon, Grid

SQUARE = [(-1000.0, -1000.0), (1000.0, -1000.0), (1000.0, 1000.0), (-1000.0, 1000.0)]


@pytest.fixture(scope="module")
def grid() -> Grid:
    # The paper's setting: 2 km x 2 km, 40 m cells, R_A = 60 m.
    return Grid.build(ConvexPolygon.from_vertices(SQUARE), 40.0, 60.0)


def centres_of(grid: Grid, cells: np.ndarray) -> set[tuple[float, float]]:
    return {(float(x), float(y)) for x, y in grid.centres[cells]}


def test_square_grid_has_2500_cells_on_the_40m_lattice(grid: Grid) -> None:
    # 2000 / 40 = 50 cells per axis; centres at -980, -940, ..., 980.
    assert grid.n_cells == 2500
    assert grid.centres[:, 0].min() == -980.0 and grid.centres[:, 0].max() == 980.0
    assert grid.centres[:, 1].min() == -980.0 and grid.centres[:, 1].max() == 980.0
    assert grid.cell_area == 1600.0
    assert grid.diagonal == pytest.approx(56.568542, rel=1e-7)  # sqrt(40^2 + 40^2)


def test_triangle_keeps_only_cells_whose_centre_is_inside() -> None:
    # Triangle (0,0), (200,0), (0,200), 40 m cells: lattice centres 20 + 40 i, i = 0..4.
    # A centre is inside iff (20 + 40 i) + (20 + 40 j) <= 200, i.e. i + j <= 4: 5+4+3+2+1 = 15 cells.
    region = ConvexPolygon.from_vertices([(0, 0), (200, 0), (0, 200)])
    g = Grid.build(region, 40.0, 60.0)
    assert g.n_cells == 15
    assert np.all(g.centres.sum(axis=1) <= 200.0 + 1e-9)
    assert region.area == pytest.approx(20000.0)  # 200 * 200 / 2
    # every lattice entry maps back to the centre at its (row, col)
    rows, cols = np.nonzero(g.lattice >= 0)
    idx = g.lattice[rows, cols]
    assert np.allclose(g.centres[idx], np.column_stack([20 + 40.0 * cols, 20 + 40.0 * rows]))


def test_clockwise_vertices_give_the_same_region() -> None:
    cw = ConvexPolygon.from_vertices(SQUARE[::-1])
    assert cw.area == pytest.approx(4.0e6)
    assert cw.contains(0.0, 0.0) is True
    assert cw.contains(1000.0, 1000.0) is True  # on the boundary counts as inside
    assert cw.contains(1000.1, 0.0) is False


def test_fov_at_a_cell_centre_is_the_3x3_block(grid: Grid) -> None:
    # Centre (20, 20): neighbours at 40 m (4) and 56.6 m (4) are within 60 m; 80 m ones are not.
    cells = grid.fov_cell_list((20.0, 20.0))
    assert len(cells) == 9
    assert centres_of(grid, cells) == {(x, y) for x in (-20.0, 20.0, 60.0) for y in (-20.0, 20.0, 60.0)}


def test_fov_is_clipped_at_region_corner_and_edge(grid: Grid) -> None:
    # Corner cell (-980, -980): only the 2x2 part of the 3x3 block exists.
    corner = grid.fov_cell_list((-980.0, -980.0))
    assert centres_of(grid, corner) == {(x, y) for x in (-980.0, -940.0) for y in (-980.0, -940.0)}
    # Edge cell (-980, 20): 2 columns x 3 rows = 6 cells.
    assert len(grid.fov_cell_list((-980.0, 20.0))) == 6


def test_fov_between_cells(grid: Grid) -> None:
    # At a lattice corner (0, 0): the 4 centres at 28.3 m; the next ring is at sqrt(20^2+60^2) = 63.2 m.
    assert centres_of(grid, grid.fov_cell_list((0.0, 0.0))) == {
        (x, y) for x in (-20.0, 20.0) for y in (-20.0, 20.0)
    }
    # Midway between (20,20) and (60,20), i.e. at (40,20): 2 centres at 20 m, 4 at 44.7 m,
    # (-20,20) and (100,20) at exactly 60 m (inside: "within R_A"), (+-40 offsets at 72 m are not).
    got = centres_of(grid, grid.fov_cell_list((40.0, 20.0)))
    assert len(got) == 8
    assert {(-20.0, 20.0), (100.0, 20.0)} <= got


def test_fov_table_rows_match_fov_cell_list(grid: Grid) -> None:
    for p in (0, 49, 1225, 2499):
        row = grid.fov_table[p]
        assert np.array_equal(np.sort(row[row < grid.n_cells]), grid.fov_cell_list(grid.centres[p]))
    assert np.all(grid.fov_table[-1] == grid.n_cells)  # the padding row


def test_cell_at(grid: Grid) -> None:
    # Cells are numbered row-major from the lower-left: index = row * 50 + col.
    # (21, -19) lies in the cell centred (20, -20): col = (20 + 980) / 40 = 25, row = 24.
    assert grid.cell_at([(21.0, -19.0)]).tolist() == [24 * 50 + 25]
    assert grid.cell_at([(-999.0, -999.0)]).tolist() == [0]
    assert grid.cell_at([(1001.0, 0.0), (0.0, -1001.0)]).tolist() == [-1, -1]


@settings(max_examples=50, deadline=None)
@given(st.floats(-1100, 1100), st.floats(-1100, 1100))
def test_fov_matches_brute_force(grid: Grid, x: float, y: float) -> None:
    d2 = np.sum((grid.centres - (x, y)) ** 2, axis=1)
    assume(np.all(np.abs(d2 - 3600.0) > 1e-3))  # no centre on the FOV circle itself
    expected = np.flatnonzero(d2 <= 3600.0)
    assert np.array_equal(grid.fov_cell_list((x, y)), expected)


def test_fov_of_many_points_has_a_fixed_width_padded_with_n_cells(grid: Grid) -> None:
    pts = np.array([[20.0, 20.0], [-980.0, -980.0], [5000.0, 5000.0]])
    table = grid.fov_cells(pts)
    assert table.shape == (3, grid.fov_offsets.shape[0])
    counts = np.sum(table < grid.n_cells, axis=1)
    assert counts.tolist() == [9, 4, 0]
    assert math.isclose(grid.fov_radius, 60.0)
