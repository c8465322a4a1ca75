"""Start layouts: UAVs on one edge of the region heading inwards, or clustered about a point inside.

The UAVs are separated and connected. The mission generator draws its missions' layouts with
`start_layout`; `uavsearch mc --random-starts` draws one per run with `random_start`, a pure
function of (mission, seed, run), so run r of every algorithm starts from the same layout.
"""

from __future__ import annotations

import math

import msgspec
import numpy as np

from companion.contracts.mission import Mission, MissionError, Vehicle
from companion.core.feasibility import validate
from companion.core.geometry import ConvexPolygon
from companion.core.search_area import region_hull

LAYOUTS = ("edge", "clustered")
ATTEMPTS = 200  # draws per run before giving up (a region too small for the swarm)
START_STREAM = 16  # spawn key of the start layout's random stream (core's `world.Stream` uses 0-3)


def _heading_deg(dx: float, dy: float, grid: bool) -> float:
    h = math.degrees(math.atan2(dy, dx))
    return float(round(h / 45) * 45 if grid else round(h, 1))


def _snap(x: float, y: float, x0: float, y0: float, cell: float) -> tuple[float, float]:
    return x0 + cell * round((x - x0) / cell), y0 + cell * round((y - y0) / cell)


def start_layout(
    rng: np.random.Generator,
    poly: ConvexPolygon,
    n: int,
    layout: str,
    grid: bool,
    cell: float,
    link: float,
) -> list[tuple[float, float, float]]:
    """Up to n start poses (x, y, heading_deg), 2-6 cells apart, on an edge or about a point.

    On an edge they head inwards; otherwise they are clustered about a point. Each is within `link`
    of another; in grid mode they sit on cell centres. The caller validates them (a clustered draw
    may also place fewer than n).
    """
    x0, y0 = poly.vertices.min(axis=0) + cell / 2
    spacing = rng.uniform(2.0, 6.0) * cell
    verts = poly.vertices
    if layout == "edge":
        e = int(rng.integers(len(verts)))
        a, b = verts[e], verts[(e + 1) % len(verts)]
        length = float(np.linalg.norm(b - a))
        spacing = min(spacing, 0.8 * link, (length - 2 * cell) / max(n - 1, 1))
        inward = -poly.normals[e]
        mid = (a + b) / 2 + inward * cell * 0.5
        along = (b - a) / length
        points = [mid + along * spacing * (i - (n - 1) / 2) for i in range(n)]
        heading = _heading_deg(inward[0], inward[1], grid)
        poses = [(float(p[0]), float(p[1]), heading) for p in points]
    elif layout == "clustered":
        lo, hi = verts.min(axis=0), verts.max(axis=0)
        while True:
            c = rng.uniform(lo, hi)
            if poly.contains(c[0], c[1]):
                break
        base = rng.uniform(-180, 180)
        poses = []
        for _ in range(50 * n):
            if len(poses) == n:
                break
            p = c + rng.normal(0, spacing * math.sqrt(n) / 2, 2) if poses else c
            far = all(math.dist(p, q[:2]) >= 1.5 * spacing / 2 + 60 for q in poses)
            near = not poses or any(math.dist(p, q[:2]) <= 0.7 * link for q in poses)
            if far and near and poly.contains(p[0], p[1]):
                h = math.radians(base + rng.uniform(-30, 30))
                poses.append((float(p[0]), float(p[1]), _heading_deg(math.cos(h), math.sin(h), grid)))
    else:
        raise ValueError(f"unknown start layout {layout!r}; choose from {', '.join(LAYOUTS)}")
    if grid:
        poses = [(*_snap(x, y, x0, y0, cell), h) for x, y, h in poses]
    return [(round(x, 1), round(y, 1), h) for x, y, h in poses]


def parse_layouts(text: str) -> tuple[str, ...]:
    """'edge,clustered' -> ('edge', 'clustered'), each checked."""
    layouts = tuple(v.strip() for v in text.split(",") if v.strip())
    for v in layouts or ("",):
        if v not in LAYOUTS:
            raise ValueError(f"unknown start layout {v!r}; choose from {', '.join(LAYOUTS)}")
    return layouts


def random_start(
    mission: Mission, seed: int, run: int, layouts: tuple[str, ...] = LAYOUTS
) -> tuple[Mission, str]:
    """The mission with the start layout of run `run` of seed `seed`, and the layout's kind.

    The same UAVs (MAVLink ports kept) are drawn anew from `layouts`, and the mission is validated
    like a mission file.
    """
    rng = np.random.default_rng(np.random.SeedSequence(entropy=seed, spawn_key=(run, START_STREAM)))
    poly = region_hull(mission)
    n, grid = mission.n_uavs, mission.kinematics.mode == "grid"
    link = mission.comms.range - mission.safety.buffer
    last = "no draw placed every UAV"
    for _ in range(ATTEMPTS):
        layout = str(rng.choice(layouts))
        poses = start_layout(rng, poly, n, layout, grid, mission.region.cell_size, link)
        if len(poses) < n:
            continue
        vehicles = [
            Vehicle(x=float(x), y=float(y), heading_deg=float(h), mavlink_port=v.mavlink_port)
            for (x, y, h), v in zip(poses, mission.vehicles, strict=True)
        ]
        try:
            checked = validate(msgspec.structs.replace(mission, vehicles=vehicles), mission.name)
        except MissionError as exc:
            last = exc.reason
            continue
        return checked, layout
    raise ValueError(
        f"{mission.name}: no valid start layout ({', '.join(layouts)}) for run {run} of seed {seed} in "
        f"{ATTEMPTS} draws (last: {last}): the region is too small for {n} UAVs"
    )
