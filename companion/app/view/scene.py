"""The static part of the map: region, grid, prior (eq. 1) and CVT task regions, as JSON."""

from __future__ import annotations

from typing import Any

import numpy as np

from companion.core.geometry import ConvexPolygon
from companion.core.world import World


def scene_json(world: World, mode: str, **extra: Any) -> dict[str, Any]:
    """Everything the page draws that does not change during the mission.

    Cells are given by lattice column and row (`grid.x0 + col * cell`, `grid.y0 + row * cell` is
    the centre); `labels[p]` is the task of cell p (the assigned region of task j is the cells
    labelled j), absent when the algorithm has no CVT.
    """
    m, grid = world.mission, world.grid
    rows, cols = np.nonzero(grid.lattice >= 0)
    order = np.argsort(grid.lattice[rows, cols])
    tess = world.tessellation
    scene: dict[str, Any] = {
        "mode": mode,
        "mission": m.name,
        "algorithm": m.algorithm.name,
        "n_uavs": m.n_uavs,
        "region": [list(map(float, v)) for v in m.region.polygon],
        "fence": fence_vertices(world.grid.region, m.safety.margin).round(3).tolist(),
        "grid": {
            "x0": grid.x0,
            "y0": grid.y0,
            "cell": grid.cell_size,
            "cols": cols[order].tolist(),
            "rows": rows[order].tolist(),
        },
        "prior": np.round(world.prior, 8).tolist(),
        "labels": tess.labels.tolist() if tess is not None else None,
        "generators": np.round(tess.generators, 3).tolist() if tess is not None else [],
        "comm_range": m.comms.range,
        "safety": m.comms.safety,
        "fov_radius": m.sensor.radius,
        "eta0": m.uncertainty.eta0,
        "gamma": m.uncertainty.gamma,
        "targets": m.prior.targets,
        "step_seconds": m.kinematics.step,
        "peer_timeout_steps": m.comms.peer_timeout_steps,
    }
    scene.update(extra)
    return scene


def fence_vertices(region: ConvexPolygon, margin: float) -> np.ndarray:
    """The fence's corners: the region with every edge pushed out by the operating `margin`, where
    the UAVs may turn outside the region to keep separation (docs/algorithm.md, "Safety layer")."""
    normals, offsets = region.normals, region.offsets + margin
    corners = [np.linalg.solve(normals[[i - 1, i]], offsets[[i - 1, i]]) for i in range(len(normals))]
    return np.array(corners)
