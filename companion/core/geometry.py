"""Convex search region and its grid of cells (section II-B) and the sensor FOV (eq. 3)."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numba import njit
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]


@njit(cache=True)
def _lattice_lookup(points: FloatArray, x0: float, y0: float, size: float, lattice: IntArray) -> IntArray:
    """Cell index (or -1) of the lattice cell nearest each point."""
    ny, nx = lattice.shape
    out = np.full(points.shape[0], -1, dtype=np.int64)
    for i in range(points.shape[0]):
        col = math.floor((points[i, 0] - x0) / size + 0.5)
        row = math.floor((points[i, 1] - y0) / size + 0.5)
        if 0 <= col < nx and 0 <= row < ny:
            out[i] = lattice[row, col]
    return out


@njit(cache=True)
def _fov_lookup(
    points: FloatArray,
    x0: float,
    y0: float,
    size: float,
    lattice: IntArray,
    offsets: IntArray,
    radius2: float,
    pad: int,
) -> IntArray:
    """Cells of the lattice stencil around each point whose centre lies within the FOV radius."""
    ny, nx = lattice.shape
    out = np.full((points.shape[0], offsets.shape[0]), pad, dtype=np.int64)
    for i in range(points.shape[0]):
        col = math.floor((points[i, 0] - x0) / size + 0.5)
        row = math.floor((points[i, 1] - y0) / size + 0.5)
        for k in range(offsets.shape[0]):
            c, r = col + offsets[k, 0], row + offsets[k, 1]
            if 0 <= c < nx and 0 <= r < ny and lattice[r, c] >= 0:
                dx, dy = x0 + size * c - points[i, 0], y0 + size * r - points[i, 1]
                if dx * dx + dy * dy <= radius2:
                    out[i, k] = lattice[r, c]
    return out


@njit(cache=True)
def _fov_list(
    x: float,
    y: float,
    x0: float,
    y0: float,
    size: float,
    lattice: IntArray,
    offsets: IntArray,
    radius2: float,
) -> IntArray:
    """The cells of `_fov_lookup` for one point, without padding, ascending."""
    point = np.empty((1, 2))
    point[0, 0], point[0, 1] = x, y
    cells = _fov_lookup(point, x0, y0, size, lattice, offsets, radius2, -1)[0]
    return np.sort(cells[cells >= 0])


@dataclass(frozen=True)
class ConvexPolygon:
    """A convex polygon stored as half-planes `normals @ p <= offsets` (counter-clockwise)."""

    vertices: FloatArray
    normals: FloatArray
    offsets: FloatArray

    @classmethod
    def from_vertices(cls, vertices: ArrayLike) -> ConvexPolygon:
        v = np.asarray(vertices, dtype=float)
        area2 = np.sum(v[:, 0] * np.roll(v[:, 1], -1) - np.roll(v[:, 0], -1) * v[:, 1])
        if area2 < 0:
            v = v[::-1].copy()
        edges = np.roll(v, -1, axis=0) - v
        normals = np.column_stack([edges[:, 1], -edges[:, 0]])
        normals /= np.linalg.norm(normals, axis=1, keepdims=True)
        offsets = np.einsum("ij,ij->i", normals, v)
        return cls(v, normals, offsets)

    def contains(self, x: ArrayLike, y: ArrayLike, tol: float = 1e-9) -> NDArray[np.bool_] | bool:
        """True where (x, y) lies inside or on the polygon."""
        xa, ya = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
        inside = np.all(
            self.normals[:, 0] * xa[..., None] + self.normals[:, 1] * ya[..., None] <= self.offsets + tol,
            axis=-1,
        )
        return bool(inside) if inside.ndim == 0 else inside

    @property
    def area(self) -> float:
        v = self.vertices
        return 0.5 * float(np.sum(v[:, 0] * np.roll(v[:, 1], -1) - np.roll(v[:, 0], -1) * v[:, 1]))

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        (x0, y0), (x1, y1) = self.vertices.min(axis=0), self.vertices.max(axis=0)
        return float(x0), float(y0), float(x1), float(y1)


@dataclass(frozen=True)
class Grid:
    """Cells c_p of size D x D whose centres mu_p lie in the region (section II-B).

    Cells sit on a lattice anchored at the region's lower-left bounding-box corner; only cells
    whose centre is inside the polygon exist. `centres[p]` is mu_p; `lattice[row, col]` maps a
    lattice position to its cell index or -1. `fov_offsets` is the lattice stencil that can hold
    cells within the FOV radius R_A of any point (eq. 3).
    """

    region: ConvexPolygon
    cell_size: float
    x0: float
    y0: float
    nx: int
    ny: int
    centres: FloatArray
    lattice: IntArray
    fov_radius: float
    fov_offsets: IntArray

    @classmethod
    def build(
        cls,
        region: ConvexPolygon,
        cell_size: float,
        fov_radius: float,
        mask: Callable[[FloatArray, FloatArray], BoolArray | None] | None = None,
    ) -> Grid:
        """The cells of `region` (a mission's hull) that `mask(x, y)` keeps (None: all of them)."""
        bx0, by0, bx1, by1 = region.bounds
        nx = max(1, math.ceil((bx1 - bx0) / cell_size - 1e-9))
        ny = max(1, math.ceil((by1 - by0) / cell_size - 1e-9))
        x0, y0 = bx0 + cell_size / 2, by0 + cell_size / 2
        cx, cy = np.meshgrid(x0 + cell_size * np.arange(nx), y0 + cell_size * np.arange(ny))
        inside = np.asarray(region.contains(cx, cy))
        kept = mask(cx, cy) if mask is not None else None
        if kept is not None:
            inside &= kept
        lattice = np.full((ny, nx), -1, dtype=np.int64)
        lattice[inside] = np.arange(int(inside.sum()))
        centres = np.column_stack([cx[inside], cy[inside]])
        reach = math.ceil(fov_radius / cell_size + 0.5)
        oy, ox = np.mgrid[-reach : reach + 1, -reach : reach + 1]
        keep = (np.hypot(ox, oy) - math.sqrt(0.5)) * cell_size <= fov_radius
        offsets = np.column_stack([ox[keep], oy[keep]]).astype(np.int64)
        return cls(region, float(cell_size), x0, y0, nx, ny, centres, lattice, fov_radius, offsets)

    @property
    def n_cells(self) -> int:
        return int(self.centres.shape[0])

    @property
    def cell_area(self) -> float:
        return self.cell_size**2

    @property
    def diagonal(self) -> float:
        """sqrt(Dx^2 + Dy^2) of eq. 16."""
        return math.sqrt(2.0) * self.cell_size

    def cell_at(self, points: ArrayLike) -> IntArray:
        """Index of the cell containing each point, or -1 outside every cell."""
        p = np.asarray(points, dtype=float)
        flat = _lattice_lookup(p.reshape(-1, 2), self.x0, self.y0, self.cell_size, self.lattice)
        return flat.reshape(p.shape[:-1])

    def fov_cells(self, points: ArrayLike) -> IntArray:
        """Eq. 3: cells whose centre is within R_A of each point.

        Returns an array of shape points.shape[:-1] + (K,) of cell indices, padded with
        `n_cells` (an index one past the last cell, so a map padded with a 0 can be gathered).
        """
        p = np.asarray(points, dtype=float)
        flat = _fov_lookup(
            p.reshape(-1, 2),
            self.x0,
            self.y0,
            self.cell_size,
            self.lattice,
            self.fov_offsets,
            self.fov_radius2,
            self.n_cells,
        )
        return flat.reshape((*p.shape[:-1], self.fov_offsets.shape[0]))

    @cached_property
    def fov_table(self) -> IntArray:
        """Eq. 3 per cell centre: row p lists the FOV of a UAV at mu_p; the last row is all padding."""
        pad = np.full((1, self.fov_offsets.shape[0]), self.n_cells)
        return np.vstack([self.fov_cells(self.centres), pad])

    @cached_property
    def lattice_neighbours(self) -> IntArray:
        """Row p: the cells below, above, left and right of cell p on the lattice (-1 where none)."""
        out = np.full((self.n_cells, 4), -1, dtype=np.int64)
        padded = np.pad(self.lattice, 1, constant_values=-1)
        rows, cols = np.nonzero(self.lattice >= 0)
        for k, (dr, dc) in enumerate(((-1, 0), (1, 0), (0, -1), (0, 1))):
            out[self.lattice[rows, cols], k] = padded[rows + 1 + dr, cols + 1 + dc]
        return out

    @cached_property
    def fov_radius2(self) -> float:
        """R_A^2 with a margin for rounding: a cell centre at exactly R_A is in view."""
        return self.fov_radius**2 + 1e-6

    def fov_cell_list(self, point: tuple[float, float] | FloatArray) -> IntArray:
        """Eq. 3 for one point (x, y): the sorted indices of the cells in its FOV."""
        x, y = point
        g = (self.x0, self.y0, self.cell_size, self.lattice, self.fov_offsets, self.fov_radius2)
        return _fov_list(float(x), float(y), *g)
