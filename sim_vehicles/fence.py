"""The simulated autopilot's fence: inclusion and exclusion polygons and circles, as ArduPlane keeps them.

Parsed from the stored fence items (mission type FENCE, local frame): a polygon is a run of
MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION (or _EXCLUSION) items, each with param1 the polygon's
vertex count; a circle is one MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION (or _EXCLUSION) item with param1
its radius (m); a return point is kept by neither. As ArduPlane's polyfence (and PX4's geofence),
the aircraft breaches when it is outside any inclusion zone or inside any exclusion zone.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import shapely
from pymavlink.dialects.v20 import ardupilotmega as mavlink
from shapely.geometry import Polygon

M = mavlink
POLYGONS = {  # command: whether the zone is an inclusion
    M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION: True, M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION: False,
}  # fmt: skip
CIRCLES = {M.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION: True, M.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION: False}
ToLocal = Callable[[float, float], tuple[float, float]]


@dataclass(frozen=True)
class FencePoint:
    """One fence item as the fence needs it: command, param1, and (lat, lon) in degrees * 1e7."""

    command: int
    param1: float
    x: int
    y: int


@dataclass(frozen=True)
class Zone:
    """One inclusion or exclusion zone in the local frame: a polygon, or a circle (`radius` > 0)."""

    inclusion: bool
    polygon: Polygon | None = None
    centre: tuple[float, float] = (0.0, 0.0)
    radius: float = 0.0

    def contains(self, x: float, y: float) -> bool:
        """Whether (x, y) is inside the zone (its boundary counts as inside)."""
        if self.polygon is not None:
            return bool(shapely.intersects_xy(self.polygon, x, y))
        return math.hypot(x - self.centre[0], y - self.centre[1]) <= self.radius

    def keeps_out(self, x: float, y: float) -> bool:
        """Whether an aircraft at (x, y) breaches this zone."""
        return self.contains(x, y) != self.inclusion


@dataclass(frozen=True)
class Fence:
    """The zones of one vehicle's fence (none: no fence)."""

    zones: tuple[Zone, ...] = ()

    def breached(self, x: float, y: float) -> bool:
        """Whether (x, y) is outside an inclusion zone or inside an exclusion zone."""
        return any(z.keeps_out(x, y) for z in self.zones)


def parse_fence(items: Sequence[FencePoint], to_local: ToLocal) -> Fence | None:
    """The fence of `items` (`to_local` maps lat, lon in degrees to the local frame); None if malformed.

    Malformed: a polygon whose items disagree on the vertex count or that has fewer than 3
    vertices, or a circle whose radius is not positive (ArduPilot's loader refuses them).
    """
    zones: list[Zone] = []
    i = 0
    while i < len(items):
        it = items[i]
        if it.command in CIRCLES:
            if not it.param1 > 0:
                return None
            centre = to_local(it.x * 1e-7, it.y * 1e-7)
            zones.append(Zone(CIRCLES[it.command], centre=centre, radius=it.param1))
            i += 1
        elif it.command in POLYGONS:
            n = int(it.param1)
            group = items[i:i + n]
            if n < 3 or len(group) < n or any(g.command != it.command or int(g.param1) != n for g in group):
                return None
            polygon = Polygon([to_local(g.x * 1e-7, g.y * 1e-7) for g in group])
            shapely.prepare(polygon)  # many point tests follow
            zones.append(Zone(POLYGONS[it.command], polygon=polygon))
            i += n
        else:  # a return point
            i += 1
    return Fence(tuple(zones))
