"""The static part of the map: region, fence, no-fly zones, grid, prior (eq. 1) and CVT tasks, as JSON."""

from __future__ import annotations

import msgspec
import numpy as np
import shapely

from companion.contracts.mission import NoFly, NoFlyCircle
from companion.core.geometry import ConvexPolygon
from companion.core.search_area import zone_shape
from companion.core.world import World


class SceneGrid(msgspec.Struct, frozen=True):
    """The search grid's cells by lattice column and row.

    Cell p's centre is (`x0 + cols[p] * cell`, `y0 + rows[p] * cell`)."""

    x0: float
    y0: float
    cell: float
    cols: list[int]
    rows: list[int]


class SceneZone(msgspec.Struct, frozen=True):
    """A no-fly zone as drawn: its polygon, its label and where it goes, and the zone inflated.

    `ring` is `search_area.zone_shape` (a circle as the polygon around it); `inflated` holds the
    rings (exterior first, then any holes) of that shape grown by the operating margin: the
    keep-out no trajectory enters (the safety layer's own polygon of it lies just outside)."""

    label: str
    at: list[float]
    ring: list[list[float]]
    inflated: list[list[list[float]]]


class Scene(msgspec.Struct, frozen=True, omit_defaults=True):
    """Everything the page draws that does not change during the mission (/api/scene).

    `labels[p]` is the task of cell p (the assigned region of task j is the cells labelled j), None
    when the algorithm has no CVT. A replay adds its run, the runs the directory holds, the
    ground truth ([cell, x, y, step found]) and its steps; `targets` is then the truth's count.
    `region` is the mission's own polygon (non-convex allowed), `fence` the convex fence around it."""

    mode: str
    mission: str
    algorithm: str
    n_uavs: int
    region: list[list[float]]
    fence: list[list[float]]
    nofly: list[SceneZone]
    grid: SceneGrid
    prior: list[float]
    labels: list[int] | None
    generators: list[list[float]]
    comm_range: float
    safety: float
    fov_radius: float
    eta0: float
    gamma: float
    targets: int
    step_seconds: float
    peer_timeout_steps: int
    seed: int
    run: int | None = None
    runs: list[list[str | int]] | None = None
    truth: list[list[float]] | None = None
    steps: int | None = None


def build_scene(world: World, mode: str, seed: int) -> Scene:
    """The `Scene` of `world` ("live" or "replay" `mode`), without a replay's fields."""
    m, grid = world.mission, world.grid
    rows, cols = np.nonzero(grid.lattice >= 0)
    order = np.argsort(grid.lattice[rows, cols])
    tess = world.tessellation
    return Scene(
        mode=mode,
        mission=m.name,
        algorithm=m.algorithm.name,
        n_uavs=m.n_uavs,
        region=[list(map(float, v)) for v in m.region.polygon],
        fence=fence_vertices(world.grid.region, m.safety.margin).round(3).tolist(),
        nofly=[scene_zone(i, z, m.safety.margin) for i, z in enumerate(m.region.nofly)],
        grid=SceneGrid(
            float(grid.x0), float(grid.y0), float(grid.cell_size), cols[order].tolist(), rows[order].tolist()
        ),
        prior=np.round(world.prior, 8).tolist(),
        labels=tess.labels.tolist() if tess is not None else None,
        generators=np.round(tess.generators, 3).tolist() if tess is not None else [],
        comm_range=m.comms.range,
        safety=m.comms.safety,
        fov_radius=m.sensor.radius,
        eta0=m.uncertainty.eta0,
        gamma=m.uncertainty.gamma,
        targets=m.prior.targets,
        step_seconds=m.kinematics.step,
        peer_timeout_steps=m.comms.peer_timeout_steps,
        seed=seed,
    )


def scene_zone(index: int, zone: NoFly, margin: float) -> SceneZone:
    """No-fly zone `index` as the map draws it, inflated by the operating `margin`."""
    shape = zone_shape(zone)
    grown = shape.buffer(margin) if margin > 0 else shape
    rings = [ring for part in shapely.get_parts(grown) for ring in (part.exterior, *part.interiors)]
    kind = f"circle r {zone.radius:g} m" if isinstance(zone, NoFlyCircle) else "polygon"
    at = shape.point_on_surface()
    return SceneZone(
        label=f"no-fly {index} ({kind})",
        at=[round(at.x, 3), round(at.y, 3)],
        ring=_coords(shape.exterior),
        inflated=[_coords(r) for r in rings],
    )


def _coords(ring: shapely.LinearRing) -> list[list[float]]:
    """An open ring's vertices (x, y), rounded to the millimetre."""
    return np.round(np.asarray(ring.coords)[:-1], 3).tolist()


def fence_vertices(region: ConvexPolygon, margin: float) -> np.ndarray:
    """The fence's corners: the region's hull with every edge pushed out by the operating `margin`.

    There the UAVs may turn outside the region to keep separation (docs/algorithm.md, "Safety
    layer"); a non-convex region's fence is its convex hull's."""
    normals, offsets = region.normals, region.offsets + margin
    corners = [np.linalg.solve(normals[[i - 1, i]], offsets[[i - 1, i]]) for i in range(len(normals))]
    return np.array(corners)
