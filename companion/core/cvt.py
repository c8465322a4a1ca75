"""Centroidal Voronoi tessellation of the grid by Lloyd's method (eqs. 8-9, Algorithm 1)."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial import cKDTree

from companion.core.geometry import BoolArray, FloatArray, IntArray
from companion.core.routes import STRAIGHT, RouteTable


@dataclass(frozen=True)
class Tessellation:
    """The tasks V_j: generators q_j, the cell labels, areas S_j and circumradii R_j."""

    generators: FloatArray
    labels: IntArray
    cell_counts: IntArray
    areas: FloatArray
    circumradii: FloatArray
    iterations: int
    routes: RouteTable = STRAIGHT  # d_ij of eq. 16 around the keep-out (`routes.route_table`)

    @property
    def n_tasks(self) -> int:
        return int(self.generators.shape[0])


def voronoi_labels(centres: FloatArray, generators: FloatArray) -> IntArray:
    """Eq. 8: each cell centre belongs to its nearest generator (ties to the lower index)."""
    _, labels = cKDTree(generators).query(centres)
    return np.asarray(labels, dtype=np.int64)


def mass_centroids(
    centres: FloatArray, density: FloatArray, labels: IntArray, generators: FloatArray
) -> FloatArray:
    """Algorithm 1, step 2: z_g = sum_{p in V_g} p rho(p) / sum_{p in V_g} rho(p).

    A region with zero mass keeps its generator.
    """
    n = generators.shape[0]
    mass = np.bincount(labels, weights=density, minlength=n)
    mx = np.bincount(labels, weights=density * centres[:, 0], minlength=n)
    my = np.bincount(labels, weights=density * centres[:, 1], minlength=n)
    out = generators.copy()
    ok = mass > 0
    out[ok, 0] = mx[ok] / mass[ok]
    out[ok, 1] = my[ok] / mass[ok]
    return out


def initial_generators(
    centres: FloatArray, density: FloatArray, n_g: int, rng: np.random.Generator
) -> FloatArray:
    """Algorithm 1's initial generators: distinct cell centres drawn in proportion to the density (Pr_p)."""
    n_g = min(n_g, centres.shape[0])
    p = density / density.sum()
    return centres[rng.choice(centres.shape[0], size=n_g, replace=False, p=p)].copy()


def lloyd_cvt(
    centres: FloatArray,
    density: FloatArray,
    n_g: int,
    rng: np.random.Generator,
    cell_area: float,
    tolerance: float = 1.0,
    max_iterations: int = 200,
) -> Tessellation:
    """Algorithm 1: replace generators by their regions' mass centroids until the mean move < epsilon."""
    generators = initial_generators(centres, density, n_g, rng)
    labels = voronoi_labels(centres, generators)
    iterations = 0
    while iterations < max_iterations:
        centroids = mass_centroids(centres, density, labels, generators)
        if float(np.mean(np.linalg.norm(centroids - generators, axis=1))) < tolerance:
            break
        generators = centroids
        labels = voronoi_labels(centres, generators)
        iterations += 1
    return describe(centres, generators, labels, cell_area, iterations)


def describe(
    centres: FloatArray, generators: FloatArray, labels: IntArray, cell_area: float, iterations: int = 0
) -> Tessellation:
    """Areas S_j and circumradii R_j (largest generator-to-cell-corner distance) of each region."""
    n = generators.shape[0]
    counts = np.bincount(labels, minlength=n)
    dist = np.linalg.norm(centres - generators[labels], axis=1) + np.sqrt(cell_area / 2.0)
    radii = np.zeros(n)
    np.maximum.at(radii, labels, dist)
    radii[radii == 0] = np.sqrt(cell_area / 2.0)
    return Tessellation(generators, labels, counts, counts * np.float64(cell_area), radii, iterations)


def onto_flyable(
    tess: Tessellation, centres: FloatArray, flyable: BoolArray, fov_radius: float
) -> Tessellation:
    """Constrained CVT: generators moved onto `flyable` cells, each task sized by the cells one can see.

    A generator not on a flyable cell centre moves to the nearest one in its region (or anywhere,
    if its region has none): a non-convex region's centroids may fall in a notch or a no-fly zone,
    where no UAV may fly to take the task (eq. 17). A task's cell count and area S_j (eqs. 16, 20)
    count only the cells within R_A of a flyable cell: the others cannot be seen, so a task that
    counted them could never be completed; a task with none is complete from the start.
    """
    generators = tess.generators.copy()
    ok = np.flatnonzero(flyable)
    tree = cKDTree(centres[ok])
    for j in range(tess.n_tasks):
        own = np.flatnonzero((tess.labels == j) & flyable)
        if own.size:
            generators[j] = centres[own[np.argmin(np.linalg.norm(centres[own] - generators[j], axis=1))]]
        else:
            generators[j] = centres[ok[int(tree.query(generators[j])[1])]]
    cell_area = float(tess.areas[0] / tess.cell_counts[0])
    moved = describe(centres, generators, tess.labels, cell_area, tess.iterations)
    seeable = np.isfinite(tree.query(centres, distance_upper_bound=fov_radius + 1e-9)[0])
    counts = np.bincount(tess.labels[seeable], minlength=tess.n_tasks)
    return replace(moved, cell_counts=counts, areas=counts * np.float64(cell_area))
