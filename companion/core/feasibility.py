"""Whether a mission can be flown: the checks that need the core's geometry.

What the mission schema cannot check without it: starts inside the region, the grid's size, a
safe start layout. Every mission the processes run is loaded through here.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path

import numpy as np
from shapely.geometry import Point

from companion.contracts.mission import (
    MAX_CVT_WORK,
    MAX_FOV_CELLS,
    MAX_FOV_TABLE,
    MAX_GRID_CELLS,
    Mission,
    MissionError,
)
from companion.contracts.mission_file import convert_schema, parse_schema, read_schema
from companion.core.geometry import ConvexPolygon
from companion.core.safety.start import minimum_margin, tether_tree
from companion.core.search_area import plain, region_hull, searchable, zone_containing
from companion.core.world import build_grid, build_kinematics, build_safety


def load_mission(path: str | Path) -> Mission:
    """Read a mission file and check it: the schema (`read_schema`), then feasibility."""
    return check_feasible(read_schema(path), str(path))


def parse_mission(text: str, source: str = "<mission>") -> Mission:
    """Mission TOML text checked as a file is (`load_mission`); `source` names it in errors."""
    return check_feasible(parse_schema(text, source), source)


def validate(mission: Mission | dict, source: str = "<mission>") -> Mission:
    """A mission built in code, checked exactly as a mission file is; returns it.

    A copy with other start poses or weights, say; a Mission or the tables of a mission file.
    """
    return check_feasible(convert_schema(mission, source), source)


def check_feasible(m: Mission, source: str) -> Mission:
    """`m` if it can be flown; else MissionError naming `source`, the field and the reason.

    It can if its starts lie in the region, its sizes are within the limits and its start layout is
    safe.
    """

    def fail(field: str, reason: str) -> None:
        raise MissionError(source, field, reason)

    region = region_hull(m)
    inside = searchable(m) if not plain(m) else None
    for i, v in enumerate(m.vehicles):
        if not region.contains(v.x, v.y) or (inside is not None and not inside.intersects(Point(v.x, v.y))):
            zone = zone_containing(m, v.x, v.y)
            where = f"inside region.nofly[{zone}]" if zone is not None else "outside region.polygon"
            fail(f"vehicles[{i}]", f"start position ({v.x}, {v.y}) is {where}")
    _validate_sizes(m, region, fail)
    _validate_start(m, fail)
    return m


def _validate_sizes(m: Mission, region: ConvexPolygon, fail: Callable[[str, str], None]) -> None:
    """The grid, the sensor footprint, the CVT and the targets within the limits above.

    Checked before anything of that size is built.
    """
    bx0, by0, bx1, by1 = region.bounds
    cell = m.region.cell_size
    across = max(bx1 - bx0, by1 - by0) / cell  # first alone: a tiny cell overflows the product
    lattice = across * across
    if across <= MAX_GRID_CELLS:
        lattice = math.ceil((bx1 - bx0) / cell) * math.ceil((by1 - by0) / cell)
    if lattice > MAX_GRID_CELLS:
        fail(
            "region.cell_size",
            f"{cell:g} m makes a grid of about {lattice:.3g} cells over the region; at most "
            f"{MAX_GRID_CELLS:,} are allowed (a larger cell size)",
        )
    stencil = (2 * math.ceil(m.sensor.radius / cell + 0.5) + 1) ** 2
    if stencil > MAX_FOV_CELLS:
        fail(
            "sensor.radius",
            f"{m.sensor.radius:g} m covers about {stencil:,} cells of {cell:g} m; at most "
            f"{MAX_FOV_CELLS:,} are allowed",
        )
    if lattice * stencil > MAX_FOV_TABLE:
        fail("sensor.radius", f"grid cells x FOV cells = {lattice * stencil:,}, over {MAX_FOV_TABLE:,}")
    n_cells = build_grid(m).n_cells
    if n_cells == 0:
        fail("region.cell_size", f"no cell of {cell:g} m has its centre inside region.polygon")
    if m.prior.targets > n_cells:
        fail("prior.targets", f"{m.prior.targets} targets, more than the grid's {n_cells} cells (one a cell)")
    a = m.algorithm
    if a.name == "proposed" and a.n_g > n_cells:
        fail("algorithm.n_g", f"{a.n_g} tasks, more than the grid's {n_cells} cells")
    if a.name == "proposed" and n_cells * a.n_g > MAX_CVT_WORK:
        fail("algorithm.n_g", f"grid cells x n_g = {n_cells * a.n_g:,}, over {MAX_CVT_WORK:,}")



def _validate_start(m: Mission, fail: Callable[[str, str], None]) -> None:
    """The safety layer's preconditions on the start (core.safety).

    A margin the UAVs can turn back in, and a start layout that is separated, connected and admits a
    contingency for every UAV.
    """
    kin = build_kinematics(m)
    horizon = m.algorithm.horizon
    need = minimum_margin(kin, horizon)
    if m.safety.margin < need:
        fail(
            "safety.margin",
            f"{m.safety.margin:g} m is too small: a UAV at the region's edge needs {need:.1f} m beyond it "
            f"to turn back (turn limit {m.kinematics.turn_limit_deg:g} deg per {m.kinematics.step:g} s step)",
        )
    c, buffer = m.comms, m.safety.buffer
    poses = [(v.x, v.y) for v in m.vehicles]
    for i in range(len(poses)):
        for j in range(i + 1, len(poses)):
            d = math.dist(poses[i], poses[j])
            if d <= c.safety + buffer:
                fail(
                    "vehicles",
                    f"vehicles {i} and {j} start {d:.1f} m apart, within the safety distance "
                    f"R_s + safety.buffer = {c.safety + buffer:g} m",
                )
    link = c.range - buffer
    _, parents = tether_tree(np.array(poses, dtype=float), link)
    apart = [i for i, p in enumerate(parents) if p < 0 and i > 0]
    if apart:
        fail(
            "vehicles",
            f"the start layout is not connected: vehicles {apart} (and any linked to them) are not within "
            f"R_c - safety.buffer = {link:g} m of the others",
        )
    try:
        build_safety(m, kin, build_grid(m).region, kin.turn_sequences(horizon)[:0])
    except ValueError as exc:
        fail("vehicles", f"the start layout admits no safe start: {exc}")
