"""The region plus its safety margin: as a polygon, as a way back inside, and as the autopilot's fence.

The fence is the region's convex polygon with every edge pushed out by the margin: the half-planes
`normals @ p <= offsets + margin` of `companion.core.geometry.ConvexPolygon`. The margin is
`mission.safety.margin` when the mission has one, else `DEFAULT_MARGIN_M`.

`upload_fence` sends the fence to the autopilot with the MAVLink mission protocol (mission type
FENCE, one MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION item per vertex) and enables it, so the
autopilot itself keeps the aircraft in the area if the companion fails. ArduPilot: FENCE_TYPE gains
the polygon bit, FENCE_ACTION "report only" becomes RTL, MAV_CMD_DO_FENCE_ENABLE. PX4: a fence is
active once uploaded (it has no DO_FENCE_ENABLE) unless it does not contain home or the vehicle,
which PX4 reports ("Geofence invalid") and ignores; GF_ACTION "none" or "warning" becomes Return.
"""

from __future__ import annotations

import logging
import time

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.contracts.frames import LocalFrame
from companion.contracts.mission import Mission
from companion.core.geometry import ConvexPolygon, FloatArray
from companion.core.search_area import region_hull
from companion.node.mission_upload import Item
from companion.node.vehicle_link import VehicleLink

log = logging.getLogger("companion")

DEFAULT_MARGIN_M = 100.0
FENCE_TYPE_POLYGON = 4
FENCE_ACTION_REPORT, FENCE_ACTION_RTL = 0, 1
VERTEX = mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION  # param1: the polygon's vertex count
GF_ACTION_WARNING, GF_ACTION_RETURN = 1, 3  # PX4's (0 none, 2 Hold, 4 terminate, 5 land)
PX4_VERDICT_S = 2.0  # how long PX4 gets to call an uploaded fence invalid


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


def upload_fence(link: VehicleLink, frame: LocalFrame, polygon: ConvexPolygon) -> str | None:
    """Upload `polygon` as the autopilot's inclusion fence and enable it; the reason on failure."""
    seen = link.state.text_count
    count = len(polygon.vertices)
    corners = [frame.to_geodetic(float(x), float(y))[:2] for x, y in polygon.vertices]
    items = [
        Item(mavlink.MAV_FRAME_GLOBAL, VERTEX, (count, 0, 0, 0), round(lat * 1e7), round(lon * 1e7))
        for lat, lon in corners
    ]
    error = link.mission.upload(mavlink.MAV_MISSION_TYPE_FENCE, items, "fence")
    if error:
        return error
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
