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

from companion.contracts.mission import Pheromone
from companion.core.geometry import FloatArray, Grid, IntArray


@njit(cache=True)
def _step(
    neighbours: IntArray,
    phi: FloatArray,
    eta: FloatArray,
    prior: FloatArray,
    deposit: float,
    evaporation: float,
    diffusion: float,
    weight: float,
    sensed: FloatArray,
) -> FloatArray:
    out = np.empty_like(phi)
    for p in range(phi.shape[0]):
        total, count = 0.0, 0
        for j in range(4):
            q = neighbours[p, j]
            if q >= 0:
                total += phi[q]
                count += 1
        mean4 = total / count if count else phi[p]
        out[p] = (1.0 - evaporation) * ((1.0 - diffusion) * phi[p] + diffusion * mean4)
        out[p] += deposit * (eta[p] * prior[p])
        sensed[p] = eta[p] + weight * out[p]
    return out


def step_field(
    grid: Grid, phi: FloatArray, eta: FloatArray, prior: FloatArray, p: Pheromone, sensed: FloatArray
) -> FloatArray:
    """One step of the pheromone field: deposit, diffusion, evaporation; returns the new field.

    The deposit is in proportion to s = eta * Pr (eq. 12); diffusion is 4-neighbour, with no flux
    across the region edge. It also writes the map the RHC senses, eta + weight * phi, into the first
    cells of `sensed`.
    """
    return _step(
        grid.lattice_neighbours, phi, eta, prior, p.deposit, p.evaporation, p.diffusion, p.weight, sensed
    )
