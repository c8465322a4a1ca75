"""The region plus its safety margin: as a polygon, as a way back inside, and as the autopilot's fence.

The planning fence is the region's convex hull with every edge pushed out by the margin: the
half-planes `normals @ p <= offsets + margin` of `companion.core.geometry.ConvexPolygon`. The margin
is `mission.safety.margin` when the mission has one, else `DEFAULT_MARGIN_M`.

`upload_fence` sends the autopilot's fence (`fence_items`: the inclusion polygon, the region pushed
out with mitred corners, then every no-fly zone as the operator gave it, an exclusion polygon or
circle) with the MAVLink mission protocol (mission type FENCE), reads it back and compares it item by
item (`fence_mismatch`), and enables it. ArduPilot: FENCE_TYPE gains the polygon bit (inclusion and
exclusion polygons and circles), FENCE_ACTION "report only" becomes RTL, MAV_CMD_DO_FENCE_ENABLE.
PX4: a fence is active once uploaded unless a zone excludes home or the vehicle, which PX4 reports
("Geofence invalid") and drops; GF_ACTION "none" or "warning" becomes Return.
"""

from __future__ import annotations

import logging
import time

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink
from shapely.geometry import Polygon
from shapely.geometry.polygon import orient

from companion.contracts.frames import LocalFrame
from companion.contracts.mission import Mission, NoFlyCircle
from companion.core.geometry import ConvexPolygon, FloatArray
from companion.core.search_area import is_convex, region_hull
from companion.node.mission_upload import Item
from companion.node.vehicle_link import VehicleLink

log = logging.getLogger("companion")

DEFAULT_MARGIN_M = 100.0
FENCE_TYPE_POLYGON = 4
FENCE_ACTION_REPORT, FENCE_ACTION_RTL = 0, 1
VERTEX = mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION  # param1: the polygon's vertex count
EXCLUSION = mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION  # param1: the polygon's vertex count
CIRCLE_EXCLUSION = mavlink.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION  # param1: the radius (m)
MITRE_LIMIT = 1e6  # a non-convex region's mitred growth, as the core's keep-out assumes (search_area)
LATLON_SLACK = 1  # 1e-7 degrees: PX4 truncates lat * 1e7 when it sends an item back
RADIUS_SLACK_M = 0.01  # a radius travels as a float32
GF_ACTION_WARNING, GF_ACTION_RETURN = 1, 3  # PX4's (0 none, 2 Hold, 4 terminate, 5 land)
PX4_VERDICT_S = 2.0  # how long PX4 gets to call an uploaded fence invalid


class FenceMismatch(RuntimeError):
    """The fence read back from the autopilot is not the one sent (the message says how)."""


def fence_margin(mission: Mission) -> float:
    """The safety margin around the region (m): `mission.safety.margin`, else the default."""
    margin = getattr(getattr(mission, "safety", None), "margin", None)
    return DEFAULT_MARGIN_M if margin is None else float(margin)


def offset_polygon(polygon: ConvexPolygon, distance: float) -> FloatArray:
    """Vertices (counter-clockwise) of `polygon` with every edge moved `distance` outwards.

    Inwards if `distance` is negative; vertex i is where the moved edges i-1 and i meet.
    """
    n, o = polygon.normals, polygon.offsets + distance
    out = np.empty_like(polygon.vertices)
    for i in range(len(n)):
        out[i] = np.linalg.solve(np.array([n[i - 1], n[i]]), np.array([o[i - 1], o[i]]))
    return out


def fence_polygon(mission: Mission, margin: float | None = None) -> ConvexPolygon:
    """The region plus the margin (default `fence_margin(mission)`)."""
    region = region_hull(mission)
    return ConvexPolygon.from_vertices(
        offset_polygon(region, fence_margin(mission) if margin is None else margin)
    )


def nearest_inside(region: ConvexPolygon, x: float, y: float, depth: float) -> tuple[float, float]:
    """The point nearest (x, y) at least `depth` metres inside `region`.

    Its centroid when the region is too small for that depth.
    """
    shrunk = offset_polygon(region, -depth)
    inner = ConvexPolygon.from_vertices(shrunk)
    if not np.all(region.normals @ shrunk.T <= region.offsets[:, None] - depth + 1e-6) or inner.area <= 0:
        c = region.vertices.mean(axis=0)
        return float(c[0]), float(c[1])
    if inner.contains(x, y):
        return x, y
    p = np.array([x, y])
    a, b = inner.vertices, np.roll(inner.vertices, -1, axis=0)
    ab = b - a
    t = np.clip(np.einsum("ij,ij->i", p - a, ab) / np.einsum("ij,ij->i", ab, ab), 0.0, 1.0)
    q = a + t[:, None] * ab
    best = q[np.argmin(np.sum((q - p) ** 2, axis=1))]
    return float(best[0]), float(best[1])


def fence_ring(mission: Mission, margin: float) -> list[tuple[float, float]]:
    """The autopilot's inclusion polygon (counter-clockwise): the region pushed out by `margin`.

    A convex region's is `fence_polygon`; a non-convex one's is the region grown with mitred corners.
    """
    ring = mission.region.polygon
    if is_convex(ring):
        return [(float(x), float(y)) for x, y in fence_polygon(mission, margin).vertices]
    grown = Polygon(ring).buffer(margin, join_style="mitre", mitre_limit=MITRE_LIMIT)
    return [(float(x), float(y)) for x, y in orient(grown).exterior.coords[:-1]]


def fence_items(mission: Mission, frame: LocalFrame, margin: float) -> list[Item]:
    """The autopilot's fence: `fence_ring` as inclusion vertices, then every no-fly zone, not inflated."""
    items = _polygon(frame, fence_ring(mission, margin), VERTEX)
    for zone in mission.region.nofly:
        if isinstance(zone, NoFlyCircle):
            lat, lon = _degrees_e7(frame, zone.x, zone.y)
            items.append(Item(mavlink.MAV_FRAME_GLOBAL, CIRCLE_EXCLUSION, (zone.radius, 0, 0, 0), lat, lon))
        else:
            ring = list(zone.ring)
            items += _polygon(frame, ring[:-1] if len(ring) > 1 and ring[0] == ring[-1] else ring, EXCLUSION)
    return items


def _degrees_e7(frame: LocalFrame, x: float, y: float) -> tuple[int, int]:
    """(lat, lon) of a local point in degrees * 1e7."""
    lat, lon, _ = frame.to_geodetic(float(x), float(y))
    return round(lat * 1e7), round(lon * 1e7)


def _polygon(frame: LocalFrame, ring: list[tuple[float, float]], command: int) -> list[Item]:
    """A polygon's vertex items (param1 the vertex count)."""
    n = len(ring)
    return [Item(mavlink.MAV_FRAME_GLOBAL, command, (n, 0, 0, 0), *_degrees_e7(frame, x, y)) for x, y in ring]


def fence_mismatch(sent: list[Item], got: list[Item]) -> str | None:
    """How the fence read back differs from the one sent, or None if it does not.

    Compared item by item: command, vertex count or circle radius, latitude and longitude (1e-7
    degrees, `LATLON_SLACK` allowed).
    """
    if len(got) != len(sent):
        return f"the autopilot holds {len(got)} fence items, {len(sent)} were sent"
    for seq, (a, b) in enumerate(zip(sent, got, strict=True)):
        if b.command != a.command:
            return f"fence item {seq} is command {b.command}, {a.command} was sent"
        if a.command == CIRCLE_EXCLUSION and abs(b.params[0] - a.params[0]) > RADIUS_SLACK_M:
            return f"fence item {seq} has radius {b.params[0]:.2f} m, {a.params[0]:.2f} m was sent"
        if a.command != CIRCLE_EXCLUSION and round(b.params[0]) != round(a.params[0]):
            return f"fence item {seq} says {b.params[0]:.0f} vertices, {a.params[0]:.0f} was sent"
        if abs(b.x - a.x) > LATLON_SLACK or abs(b.y - a.y) > LATLON_SLACK:
            return f"fence item {seq} is at {b.x} {b.y} (1e-7 deg), {a.x} {a.y} was sent"
    return None


def upload_fence(link: VehicleLink, items: list[Item]) -> str | None:
    """Upload `items` as the autopilot's fence, check it reads back the same, enable it.

    The reason on failure; FenceMismatch if the fence read back differs from `items`.
    """
    seen = link.state.text_count
    fence = mavlink.MAV_MISSION_TYPE_FENCE
    error = link.mission.upload(fence, items, "fence")
    if error:
        return error
    got, error = link.mission.download(fence, "fence")
    error = error or fence_mismatch(items, got)
    if error:
        raise FenceMismatch(f"the autopilot's fence does not read back as sent: {error}")
    if link.state.px4:
        return _px4_fence_in_force(link, seen)
    params = link.params.read(["FENCE_TYPE", "FENCE_ACTION"])
    if "FENCE_TYPE" in params and not int(params["FENCE_TYPE"]) & FENCE_TYPE_POLYGON:
        link.params.set("FENCE_TYPE", float(int(params["FENCE_TYPE"]) | FENCE_TYPE_POLYGON))
    if params.get("FENCE_ACTION") == FENCE_ACTION_REPORT:
        log.info("fence: FENCE_ACTION was 'report only'; setting RTL")
        link.params.set("FENCE_ACTION", FENCE_ACTION_RTL)
    result = link.command_ack(mavlink.MAV_CMD_DO_FENCE_ENABLE, 1)
    if result != mavlink.MAV_RESULT_ACCEPTED and not link.params.set("FENCE_ENABLE", 1.0):
        return (
            f"the autopilot did not enable the fence (DO_FENCE_ENABLE result {result}, FENCE_ENABLE not set)"
        )
    return None


def _px4_fence_in_force(link: VehicleLink, seen: int) -> str | None:
    """PX4, after the upload: GF_ACTION none/warning becomes Return; the reason if PX4 rejects the fence."""
    action = link.params.read(["GF_ACTION"]).get("GF_ACTION")
    if action is not None and action <= GF_ACTION_WARNING:
        log.info("fence: GF_ACTION was %d (no action); setting Return", action)
        link.params.set("GF_ACTION", GF_ACTION_RETURN)
    deadline = time.monotonic() + PX4_VERDICT_S
    while time.monotonic() < deadline:
        link.poll(0.1)
    invalid = [t for t in link.state.texts_since(seen) if "Geofence invalid" in t]
    return f"PX4 ignores the fence: {invalid[0]}" if invalid else None
