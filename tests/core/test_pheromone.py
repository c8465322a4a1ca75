"""The pheromone baseline's field: deposit, 4-neighbour diffusion without flux across the edge, and
evaporation (companion.core.pheromone)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.contracts.mission import Pheromone
from companion.core import pheromone
from companion.core.geometry import ConvexPolygon, Grid


def step_field(
    grid: Grid, phi: np.ndarray, eta: np.ndarray, prior: np.ndarray, q: float, rho: float, d: float
) -> np.ndarray:
    """The new field; checks on the way that the sensed map is eta + weight * phi (weight 0.5)."""
    sensed = np.full(grid.n_cells + 1, np.nan)
    params = Pheromone(deposit=q, evaporation=rho, diffusion=d, weight=0.5)
    out = pheromone.step_field(grid, phi, eta, prior, params, sensed)
    assert sensed[:-1] == pytest.approx(eta + 0.5 * out)
    return out


@pytest.fixture(scope="module")
def square() -> Grid:
    # 3 x 3 cells of 40 m, row-major from the bottom left: cell 4 is the centre
    return Grid.build(ConvexPolygon.from_vertices([(0, 0), (120, 0), (120, 120), (0, 120)]), 40.0, 60.0)


@pytest.fixture(scope="module")
def hexagon() -> Grid:
    # an irregular lattice: cells along the slanted edges have fewer than four neighbours
    corners = [(-400, -200), (0, -420), (400, -200), (400, 200), (0, 420), (-400, 200)]
    return Grid.build(ConvexPolygon.from_vertices(corners), 40.0, 60.0)


def test_lattice_neighbours_of_the_square(square: Grid) -> None:
    nbrs = square.lattice_neighbours
    assert nbrs[4].tolist() == [1, 7, 3, 5]  # below, above, left, right
    assert nbrs[0].tolist() == [-1, 3, -1, 1]
    assert nbrs[8].tolist() == [5, -1, 7, -1]


def test_lattice_neighbours_are_mutual_and_one_cell_apart(hexagon: Grid) -> None:
    g = hexagon
    for p, row in enumerate(g.lattice_neighbours):
        for q in row[row >= 0]:
            assert p in g.lattice_neighbours[q]
            assert np.abs(g.centres[q] - g.centres[p]).sum() == pytest.approx(g.cell_size)
    # every pair of cells one cell apart along an axis is listed
    d = np.abs(g.centres[:, None, :] - g.centres[None, :, :]).sum(axis=-1)
    assert (np.isclose(d, g.cell_size)).sum() == (g.lattice_neighbours >= 0).sum()


def test_diffusion_and_evaporation_by_hand(square: Grid) -> None:
    # phi = 1 on the centre only, no deposit, rho = 0.1, D = 0.5:
    #   centre: 0.9 * (0.5 * 1 + 0.5 * 0) = 0.45
    #   edge cell (3 neighbours, one of them the centre): 0.9 * (0 + 0.5 * 1/3) = 0.15
    #   corner (neighbours 0): 0
    phi = np.zeros(9)
    phi[4] = 1.0
    out = step_field(square, phi, np.ones(9), np.zeros(9), 2.0, 0.1, 0.5)
    assert out[4] == pytest.approx(0.45)
    assert out[[1, 3, 5, 7]] == pytest.approx([0.15] * 4)
    assert out[[0, 2, 6, 8]] == pytest.approx([0.0] * 4)


def test_deposit_follows_importance(square: Grid) -> None:
    # an empty field receives q * s = q * eta * Pr (eq. 12)
    eta, prior = np.linspace(0.1, 0.9, 9), np.linspace(1.0, 0.2, 9)
    out = step_field(square, np.zeros(9), eta, prior, 2.0, 0.1, 0.5)
    assert out == pytest.approx(2.0 * eta * prior)


@settings(max_examples=30, deadline=None)
@given(st.floats(0.0, 5.0), st.floats(0.0, 1.0), st.floats(0.0, 1.0))
def test_a_uniform_field_stays_uniform_and_only_evaporates(
    hexagon: Grid, level: float, rho: float, diffusion: float
) -> None:
    """No flux across the region edge: diffusion alone leaves a uniform field as it is."""
    n = hexagon.n_cells
    out = step_field(hexagon, np.full(n, level), np.ones(n), np.zeros(n), 1.0, rho, diffusion)
    assert out == pytest.approx(np.full(n, (1 - rho) * level))


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**32 - 1), st.floats(0.0, 1.0))
def test_diffusion_keeps_the_field_within_its_bounds(hexagon: Grid, seed: int, d: float) -> None:
    """Without deposit or evaporation the field stays within its bounds (a mean of neighbours)."""
    n = hexagon.n_cells
    phi = np.random.default_rng(seed).random(n)
    out = step_field(hexagon, phi, np.ones(n), np.zeros(n), 1.0, 0.0, d)
    assert out.min() >= phi.min() - 1e-12
    assert out.max() <= phi.max() + 1e-12
