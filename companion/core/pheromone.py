"""The pheromone baseline's field (section IV; its form is not in the paper, so defined here).

Each UAV keeps a digital pheromone field phi over the cells of its own map. Every step, cells
release pheromone in proportion to their importance s = eta * Pr (eq. 12); the field diffuses to
the four lattice neighbours and evaporates:

    phi <- (1 - rho) * ((1 - D) * phi + D * mean_4(phi)) + q * s

Because s falls as a cell is searched, the deposit stops where the UAVs have been and the field
fades there. The UAV senses the field like its uncertainty map, through its FOV along each
predicted path: its RHC adds weight * sum_m sum_{p in C(w_m)} phi_p to the uncertainty-based search
benefit of eq. 25 (so it goes for high uncertainty, and is drawn towards important areas whose
pheromone has spread to where it can sense it).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from companion.core.geometry import FloatArray, Grid, IntArray


@njit(cache=True)
def _step(
    lattice: IntArray,
    phi: FloatArray,
    importance: FloatArray,
    deposit: float,
    evaporation: float,
    diffusion: float,
) -> FloatArray:
    ny, nx = lattice.shape
    out = np.empty_like(phi)
    for r in range(ny):
        for c in range(nx):
            p = lattice[r, c]
            if p < 0:
                continue
            total, count = 0.0, 0
            for dr, dc in ((-1, 0), (1, 0), (0, -1), (0, 1)):
                rr, cc = r + dr, c + dc
                if 0 <= rr < ny and 0 <= cc < nx and lattice[rr, cc] >= 0:
                    total += phi[lattice[rr, cc]]
                    count += 1
            mean4 = total / count if count else phi[p]
            out[p] = (1.0 - evaporation) * ((1.0 - diffusion) * phi[p] + diffusion * mean4)
            out[p] += deposit * importance[p]
    return out


def step_field(
    grid: Grid, phi: FloatArray, importance: FloatArray, deposit: float, evaporation: float, diffusion: float
) -> FloatArray:
    """One step of deposit, 4-neighbour diffusion (no flux across the region edge) and evaporation."""
    return _step(grid.lattice, phi, importance, deposit, evaporation, diffusion)
