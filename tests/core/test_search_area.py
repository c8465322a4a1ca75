"""No-fly zones and non-convex regions (docs/algorithm.md, "No-fly zones"): the keep-out's geometry
against shapely, the grid's cells, the constrained CVT, and runs of every algorithm that never put a
sampling point or a chord into a zone inflated by the margin."""

from __future__ import annotations

import math
from pathlib import Path

import msgspec
import numpy as np
import pytest
import shapely
from hypothesis import given, settings
from hypothesis import strategies as st
from shapely.geometry import LineString, Point, Polygon

from companion.batch.engine import simulate
from companion.contracts.mission import ALGORITHMS, Mission, NoFlyCircle, NoFlyPolygon
from companion.core.feasibility import load_mission, validate
from companion.core.routes import STRAIGHT, route_distance
from companion.core.search_area import (
    clear_of,
    flyable_cells,
    inflate,
    keepout_pieces,
    region_hull,
    zone_shape,
)
from companion.core.world import build_grid, build_world

ROOT = Path(__file__).resolve().parents[2]
NOFLY = ROOT / "mission_files" / "scenario1_nofly.toml"
L_SHAPE = [(-1000.0, -1000.0), (1000.0, -1000.0), (1000.0, 0.0), (0.0, 0.0), (0.0, 1000.0), (-1000.0, 1000.0)]
coordinate = st.floats(-1500, 1500, allow_nan=False)


def l_shaped(mode: str = "grid") -> Mission:
    """Scenario 1 cut to an L (its north-east quarter gone), with a circle zone in the west."""
    m = load_mission(ROOT / "mission_files" / "scenario1.toml")
    region = msgspec.structs.replace(
        m.region, polygon=L_SHAPE, nofly=[NoFlyCircle(x=-500.0, y=500.0, radius=150.0)]
    )
    prior = msgspec.structs.replace(m.prior, targets=5)
    kin = msgspec.structs.replace(m.kinematics, mode=mode)
    if mode == "continuous":
        kin = msgspec.structs.replace(kin, turn_limit_deg=30.0)
    return validate(msgspec.structs.replace(m, region=region, prior=prior, kinematics=kin), "l-shaped")


@settings(max_examples=300, deadline=None)
@given(coordinate, coordinate, coordinate, coordinate)
def test_a_chord_is_clear_exactly_when_it_misses_every_piece(
    x0: float, y0: float, x1: float, y1: float
) -> None:
    m = l_shaped()
    pieces = keepout_pieces(m, region_hull(m), m.safety.margin, m.safety.margin)
    shapes = [Polygon(_corners(p)) for p in pieces]
    chord = LineString([(x0, y0), (x1, y1)]) if (x0, y0) != (x1, y1) else Point(x0, y0)
    if any(0 < s.boundary.distance(chord) < 1e-6 or s.touches(chord) for s in shapes):
        return  # on an edge: either answer is right
    hits = any(s.intersects(chord) for s in shapes)
    assert clear_of(np.array([[x0, y0], [x1, y1]]), pieces) == (not hits)


@settings(max_examples=300, deadline=None)
@given(coordinate, coordinate, st.sampled_from([0.0, 7.5]))
def test_the_keepout_is_the_fence_less_what_may_be_flown(x: float, y: float, sag: float) -> None:
    """A point inside the fence is clear of the keep-out exactly when it lies in the region pushed
    out by the margin less the sagitta, and outside every zone inflated by the margin plus it."""
    m = l_shaped()
    reach = m.safety.margin - sag
    pieces = keepout_pieces(m, region_hull(m), reach, m.safety.margin + sag)
    grown = Polygon(m.region.polygon).buffer(reach, join_style="mitre", mitre_limit=1e6)
    inflated = shapely.union_all([inflate(zone_shape(z), m.safety.margin + sag) for z in m.region.nofly])
    fence = Polygon(L_SHAPE).convex_hull.buffer(reach, join_style="mitre", mitre_limit=1e6)
    point = Point(x, y)
    edges = (fence.exterior, grown.exterior, inflated.exterior)
    if not fence.contains(point) or min(e.distance(point) for e in edges) < 1e-6:
        return  # outside the fence (its half-planes' job) or on an edge
    expected = grown.contains(point) and not inflated.contains(point)
    assert clear_of(np.array([[x, y]]), pieces) == expected
    assert inflated.contains(zone_shape(m.region.nofly[0]).buffer(m.safety.margin + sag - 1e-6))


def _corners(piece: np.ndarray) -> list[tuple[float, float]]:
    """A triangle's corners from its three half-planes."""
    out = []
    for i in range(3):
        a, b = piece[i - 1], piece[i]
        out.append(tuple(np.linalg.solve(np.array([a[:2], b[:2]]), np.array([a[2], b[2]]))))
    return out


def test_cells_lie_in_the_region_and_outside_every_zone() -> None:
    for m in (load_mission(NOFLY), l_shaped()):
        grid = build_grid(m)
        region = Polygon(m.region.polygon)
        zones = shapely.union_all([zone_shape(z) for z in m.region.nofly])
        points = shapely.points(grid.centres)
        assert np.all(shapely.intersects(region, points))
        assert not np.any(shapely.contains(zones, points))
        lattice = grid.x0 + grid.cell_size * np.arange(grid.nx)
        assert grid.n_cells < len(lattice) * grid.ny  # some of the hull's cells were dropped


def test_the_constrained_cvt_puts_every_task_where_a_uav_may_fly() -> None:
    for m in (load_mission(NOFLY), l_shaped()):
        world = build_world(m, 1, 0)
        assert world.tessellation is not None
        lim = world.safety.limits
        flyable = world.grid.centres[flyable_cells(world.grid, (lim.keepout, lim.fan_keepout))]
        for g in world.tessellation.generators:
            assert np.min(np.hypot(*(flyable - g).T)) < 1e-9, g


def test_a_start_inside_a_zone_is_a_mission_error() -> None:
    m = load_mission(NOFLY)
    zone = NoFlyPolygon(ring=[(-900.0, -995.0), (900.0, -995.0), (900.0, -900.0), (-900.0, -900.0)])
    bad = msgspec.structs.replace(m, region=msgspec.structs.replace(m.region, nofly=[zone]))
    with pytest.raises(ValueError, match=r"vehicles\[0\].*inside region.nofly\[0\]"):
        validate(bad, "covered")


@pytest.mark.parametrize("algorithm", ALGORITHMS)
@pytest.mark.parametrize("case", ["nofly-band", "l-shaped-continuous"])
def test_no_run_enters_a_zone_or_loses_separation(algorithm: str, case: str) -> None:
    m = load_mission(NOFLY) if case == "nofly-band" else l_shaped("continuous")
    r = simulate(m.with_algorithm(algorithm), 3, 1, 400, kills={1: 150})
    assert r.keepout_entries == 0
    assert r.separation_losses == 0


def test_routes_go_around_the_zone_and_never_undercut_a_straight_line() -> None:
    """Eqs. 16 and 25 read route distances: never shorter than the straight line (8-neighbour
    moves overestimate it by at most 1 - 1/(2 - sqrt 2) ~ 8 %, plus a cell), and around the band
    for a point straight across it."""
    m = load_mission(NOFLY)
    world = build_world(m, 1, 0)
    tess = world.tessellation
    assert tess is not None and tess.routes[0].shape[0] == tess.n_tasks
    south = int(np.argmin(np.hypot(*(tess.generators - np.array([0.0, -200.0])).T)))
    gx, gy = tess.generators[south]
    rng = np.random.default_rng(5)
    for x, y in rng.uniform(-1000, 1000, (200, 2)):
        d = route_distance(tess.routes, south, x, y, gx, gy)
        assert d >= math.hypot(x - gx, y - gy) - 1e-6
    across = route_distance(tess.routes, south, gx, 700.0, gx, gy)  # north of the band, straight up
    around = math.hypot(450.0 + 300.0 - gx, 300.0 - gy) + math.hypot(450.0 + 300.0 - gx, 700.0 - 300.0)
    assert across > 0.9 * around > (700.0 - gy)
    assert route_distance(STRAIGHT, 0, 3.0, 4.0, 0.0, 0.0) == 5.0


def test_a_convex_regions_keepout_is_its_zones_inside_the_fence() -> None:
    """The keep-out's triangles cover exactly the zones inflated, clipped to the fence: on this
    generated triangle with three zones, one overlay of the zones with the region grown by the
    margin (whose edges are the fence's) once lost the whole difference and kept out everything."""
    m = load_mission(ROOT / "mission_files" / "scenario1.toml")
    zones = [
        NoFlyPolygon(ring=[(300.5, -1327.4), (-1139.0, -338.0), (-1199.9, -426.8), (239.6, -1416.2)]),
        NoFlyPolygon(ring=[(-305.2, -1374.5), (-764.7, 50.7), (-885.6, 11.7), (-426.1, -1413.5)]),
        NoFlyCircle(x=-581.9, y=-260.8, radius=389.4),
    ]
    triangle = [(-1835.7, 243.9), (1064.8, -1665.8), (-423.2, 1943.6)]
    region = msgspec.structs.replace(m.region, polygon=triangle, nofly=zones)
    m = msgspec.structs.replace(m, region=region)
    hull = region_hull(m)
    pieces = keepout_pieces(m, hull, 100.0, 147.0)
    covered = shapely.union_all([Polygon(_corners(p)) for p in pieces])
    fence = Polygon(triangle).buffer(100.0, join_style="mitre", mitre_limit=1e6)
    expected = fence.intersection(shapely.union_all([inflate(zone_shape(z), 147.0) for z in zones]))
    assert covered.symmetric_difference(expected).area < 1.0
    assert expected.area < 0.5 * fence.area
