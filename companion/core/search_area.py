"""The search area's shapes: its convex hull (the fence's half-planes), its cells, its keep-out pieces.

A region may be non-convex and hold no-fly zones (`Region.nofly`). The safety layer keeps its
convex fence, the hull pushed out by the operating margin, and adds the keep-out: what lies inside
that fence but outside the region pushed out by the margin, plus every zone inflated by the margin,
cut into triangles (docs/algorithm.md, "No-fly zones"). A convex region without zones has no
keep-out, so every check on it is the convex one.
"""

from __future__ import annotations

import math

import numpy as np
import shapely
from numba import njit
from shapely.geometry import Point, Polygon

from companion.contracts.mission import Mission, NoFly, NoFlyCircle
from companion.core.geometry import BoolArray, ConvexPolygon, FloatArray, Grid

CIRCLE_SEGMENTS = 16  # a no-fly circle's polygon: segments per quarter, circumscribed
ROUND_SEGMENTS = 4  # the inflation's round corners: segments per quarter, circumscribed
NO_KEEPOUT = np.zeros((0, 3, 3))
MIN_PIECE_M2 = 1e-3  # a triangle smaller is a sliver of an overlay along the fence


def is_convex(ring: list[tuple[float, float]]) -> bool:
    """Whether a simple ring turns one way only (collinear vertices allowed)."""
    v = np.asarray(ring, dtype=float)
    e = np.roll(v, -1, axis=0) - v
    cross = e[:, 0] * np.roll(e[:, 1], -1) - e[:, 1] * np.roll(e[:, 0], -1)
    return bool(np.all(cross >= -1e-9) or np.all(cross <= 1e-9))


def region_hull(mission: Mission) -> ConvexPolygon:
    """The region's convex hull as half-planes: the region itself when it is convex."""
    ring = mission.region.polygon
    if is_convex(ring):
        return ConvexPolygon.from_vertices(ring)
    hull = Polygon(ring).convex_hull.exterior.coords[:-1]
    return ConvexPolygon.from_vertices(shapely.Polygon(hull).simplify(0).exterior.coords[:-1])


def zone_shape(zone: NoFly) -> Polygon:
    """A zone as a polygon that covers it (a circle as the polygon circumscribing it)."""
    if isinstance(zone, NoFlyCircle):
        radius = zone.radius / math.cos(math.pi / (4 * CIRCLE_SEGMENTS))
        return Point(zone.x, zone.y).buffer(radius, quad_segs=CIRCLE_SEGMENTS)
    return Polygon(zone.ring)


def plain(mission: Mission) -> bool:
    """Whether the region is convex and has no no-fly zone (so no keep-out and no cell mask)."""
    return not mission.region.nofly and is_convex(mission.region.polygon)


def searchable(mission: Mission) -> shapely.Geometry:
    """What is searched: the region less every no-fly zone."""
    zones = [zone_shape(z) for z in mission.region.nofly]
    region = Polygon(mission.region.polygon)
    return region.difference(shapely.union_all(zones)) if zones else region


def zone_containing(mission: Mission, x: float, y: float) -> int | None:
    """The index of the first no-fly zone holding (x, y), if any."""
    for i, zone in enumerate(mission.region.nofly):
        if zone_shape(zone).intersects(Point(x, y)):
            return i
    return None


def inflate(shape: shapely.Geometry, distance: float) -> shapely.Geometry:
    """`shape` grown by `distance` with round corners, as a polygon that covers the true growth."""
    if distance <= 0:
        return shape
    return shape.buffer(distance / math.cos(math.pi / (4 * ROUND_SEGMENTS)), quad_segs=ROUND_SEGMENTS)


def fence_shape(hull: ConvexPolygon, distance: float) -> Polygon:
    """The hull with every edge pushed `distance` outwards (the half-planes' own polygon)."""
    n, o = hull.normals, hull.offsets + distance
    corners = [np.linalg.solve(n[[i - 1, i]], o[[i - 1, i]]) for i in range(len(n))]
    return Polygon(corners)


def keepout_pieces(
    mission: Mission, hull: ConvexPolygon, reach: float, zone_reach: float, notches: bool = True
) -> FloatArray:
    """The keep-out inside the fence as triangles, each three half-planes (nx, ny, offset): (k, 3, 3).

    The fence is the hull pushed out by `reach`; what may be flown is the region pushed out as far
    (mitred, as the fence; with `notches` False, the whole fence) less every zone inflated by
    `zone_reach`. Empty when nothing inside the fence is kept out.
    """
    if plain(mission) or (not notches and not mission.region.nofly):
        return NO_KEEPOUT
    fence = fence_shape(hull, reach)
    parts = []
    if notches and not is_convex(mission.region.polygon):
        grown = Polygon(mission.region.polygon).buffer(reach, join_style="mitre", mitre_limit=1e6)
        parts.append(fence.difference(grown))  # the notches (edges shared with the fence: slivers)
    zones = [inflate(zone_shape(z), zone_reach) for z in mission.region.nofly]
    if zones:
        parts.append(fence.intersection(shapely.union_all(zones)))
    out = []
    for part in parts:  # apart: an overlay of the zones with a region sharing the fence's edges lost all
        for t in shapely.get_parts(shapely.constrained_delaunay_triangles(part)):
            if t.area > MIN_PIECE_M2:
                out.append(_half_planes(np.asarray(t.exterior.coords[:3], dtype=float)))
    return np.array(out, dtype=float).reshape(-1, 3, 3)


def _half_planes(v: FloatArray) -> FloatArray:
    """A triangle's three outward half-planes (nx, ny, offset) from its corners."""
    if (v[1, 0] - v[0, 0]) * (v[2, 1] - v[0, 1]) - (v[1, 1] - v[0, 1]) * (v[2, 0] - v[0, 0]) < 0:
        v = v[::-1]
    e = np.roll(v, -1, axis=0) - v
    n = np.column_stack([e[:, 1], -e[:, 0]])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    return np.column_stack([n, np.einsum("ij,ij->i", n, v)])


def flyable_cells(grid: Grid, keepouts: tuple[FloatArray, FloatArray]) -> BoolArray:
    """Which cell centres a path's point may lie on: clear of the paths' and the fans' keep-out.

    `keepouts` is (`Limits.keepout`, `Limits.fan_keepout`); a task's point must be one (eq. 17).
    """
    return np.array([all(clear_of(c[None, :], k) for k in keepouts) for c in grid.centres], dtype=bool)


def cell_mask(mission: Mission, x: FloatArray, y: FloatArray) -> BoolArray | None:
    """Which points (x, y) may be searched (in the region, outside every zone); None if all in the hull."""
    if plain(mission):
        return None
    return np.asarray(shapely.intersects_xy(searchable(mission), x, y), dtype=bool)


@njit(cache=True)
def clear_of(pts: FloatArray, pieces: FloatArray) -> bool:
    """Whether no sampling point and no chord between consecutive points enters a keep-out piece.

    Each piece is a convex polygon of half-planes n . p <= offset; a chord is clipped against them
    (Cyrus-Beck), so a chord that only crosses a piece is caught as well as a point inside it.
    """
    last = pts.shape[0] - 1
    for k in range(pieces.shape[0]):
        for t in range(max(last, 1)):
            a, b = pts[t], pts[min(t + 1, last)]
            lo, hi, outside = 0.0, 1.0, False
            for e in range(pieces.shape[1]):
                fa = pieces[k, e, 0] * a[0] + pieces[k, e, 1] * a[1] - pieces[k, e, 2]
                fb = pieces[k, e, 0] * b[0] + pieces[k, e, 1] * b[1] - pieces[k, e, 2]
                if fa > 0 and fb > 0:
                    outside = True
                    break
                if fa > 0:
                    lo = max(lo, fa / (fa - fb))
                elif fb > 0:
                    hi = min(hi, fa / (fa - fb))
            if not outside and lo <= hi:
                return False
    return True


@njit(cache=True)
def keepout_entries(before: FloatArray, after: FloatArray, pieces: FloatArray) -> int:
    """How many UAVs' chords from `before` to `after` (n, 2) enter a keep-out piece."""
    count = 0
    chord = np.empty((2, 2))
    for i in range(before.shape[0]):
        chord[0], chord[1] = before[i], after[i]
        if not clear_of(chord, pieces):
            count += 1
    return count


@njit(cache=True)
def spokes_clear(pts: FloatArray, entry: int, cx: float, cy: float, pieces: FloatArray) -> bool:
    """Whether the spokes from a path's points up to its loiter's entry to the centre miss every piece.

    A failsafe region (docs/algorithm.md, "The contingency clause") is the fan of these spokes
    inflated by the failsafe's reach and stray; checked against the zones inflated by as much more,
    its edges and centre keep the region out of them (no piece fits inside a fan: each is part of a
    zone inflated by more than a fan is wide).
    """
    spoke = np.empty((2, 2))
    spoke[1, 0], spoke[1, 1] = cx, cy
    for i in range(min(entry, pts.shape[0] - 1) + 1):
        spoke[0] = pts[i]
        if not clear_of(spoke, pieces):
            return False
    return True
