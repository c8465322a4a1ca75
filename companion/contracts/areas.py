"""Search areas and no-fly zones from the operator's own files: QGroundControl .plan, GeoJSON, KML.

`read_area` reads one file into an `Area` (latitude/longitude, validated); `local_area` projects it
into a mission's local frame. Every problem is one `MissionError(file, field, reason)`; what the
reader ignores it returns as notes, never printed. Formats, no-fly markings, the origin rule and
the limits: docs/mission-files.md, "Areas from a ground station or GIS".
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from pathlib import Path

import msgspec
import shapely
from shapely.geometry import Point, Polygon
from shapely.validation import explain_validity

from companion.contracts.area_readers import Found, LatLon, read_found
from companion.contracts.frames import LocalFrame
from companion.contracts.mission import (
    MAX_FILE_BYTES,
    MAX_GRID_CELLS,
    MAX_VERTICES,
    MAX_ZONES,
    MissionError,
    Origin,
)

XY = tuple[float, float]  # (x east, y north), metres
AREA_CELL_M = 40.0  # the paper's cell: the area limit is MAX_GRID_CELLS of them
MAX_AREA_M2 = MAX_GRID_CELLS * AREA_CELL_M**2  # 400 km^2: the inclusion polygon's bounding box

MIN_AREA_M2 = 1.0  # a ring enclosing less is degenerate
ORIGIN_DECIMALS = 7  # the area's own origin, rounded to MAVLink's 1e-7 degree
CIRCLE_SEGMENTS = 64  # a circle's polygon (quarter-circle segments) in the coverage checks


class _Frozen(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True):
    """Immutable, keyword-only, strict about unknown fields."""


class ZonePolygon(_Frozen, frozen=True, tag="polygon"):
    """A no-fly polygon: an open ring of (lat, lon), counter-clockwise."""

    ring: tuple[LatLon, ...]


class ZoneCircle(_Frozen, frozen=True, tag="circle"):
    """A no-fly circle: centre (lat, lon) and radius in metres."""

    lat: float
    lon: float
    radius: float


class Area(_Frozen, frozen=True):
    """An operator's search area: the inclusion ring and the no-fly zones in lat/lon, plus notes.

    Rings are open (no repeated closing vertex), counter-clockwise, and start at their southernmost
    (then westernmost) vertex, so that one area gives one `Area` whatever the file's format.
    """

    source: str
    kind: str  # "QGroundControl plan", "GeoJSON" or "KML"
    inclusion: tuple[LatLon, ...]
    nofly: tuple[ZonePolygon | ZoneCircle, ...] = ()
    notes: tuple[str, ...] = ()

    @property
    def origin(self) -> Origin:
        """The area's own origin: the inclusion polygon's centroid (in degrees), rounded to 1e-7."""
        c = Polygon([(lon, lat) for lat, lon in self.inclusion]).centroid
        return Origin(lat=round(c.y, ORIGIN_DECIMALS), lon=round(c.x, ORIGIN_DECIMALS))


class LocalPolygon(_Frozen, frozen=True, tag="polygon"):
    """A no-fly polygon in local metres."""

    ring: tuple[XY, ...]


class LocalCircle(_Frozen, frozen=True, tag="circle"):
    """A no-fly circle in local metres."""

    x: float
    y: float
    radius: float


class LocalArea(_Frozen, frozen=True):
    """An `Area` in a local frame: (x east, y north) metres around `origin`."""

    source: str
    origin: Origin
    inclusion: tuple[XY, ...]
    nofly: tuple[LocalPolygon | LocalCircle, ...] = ()
    notes: tuple[str, ...] = ()

    @property
    def polygon(self) -> Polygon:
        """The inclusion polygon (shapely)."""
        return Polygon(self.inclusion)

    def zone_shapes(self) -> list[Polygon]:
        """Each no-fly zone as a shapely polygon (a circle as a 4 x CIRCLE_SEGMENTS-gon around it)."""
        return [_zone_shape(z) for z in self.nofly]

    @property
    def free(self) -> shapely.Geometry:
        """What may be searched: the inclusion polygon less every no-fly zone."""
        return self.polygon.difference(shapely.union_all(self.zone_shapes()))


def _zone_shape(zone: LocalPolygon | LocalCircle) -> Polygon:
    """A zone as a shapely polygon: a circle as the polygon around it, so that it covers the circle."""
    if isinstance(zone, LocalPolygon):
        return Polygon(zone.ring)
    circumscribed = zone.radius / math.cos(math.pi / (4 * CIRCLE_SEGMENTS))  # the circle inside it
    return Point(zone.x, zone.y).buffer(circumscribed, quad_segs=CIRCLE_SEGMENTS)


def local_area(area: Area, origin: Origin | None = None) -> LocalArea:
    """`area` in the local frame around `origin` (default: the area's own, `Area.origin`)."""
    origin = origin or area.origin
    frame = LocalFrame(origin)

    def ring(points: Sequence[LatLon]) -> tuple[XY, ...]:
        """A (lat, lon) ring in local metres."""
        return tuple(frame.to_local(lat, lon) for lat, lon in points)

    zones: list[LocalPolygon | LocalCircle] = []
    for z in area.nofly:
        if isinstance(z, ZonePolygon):
            zones.append(LocalPolygon(ring=ring(z.ring)))
        else:
            x, y = frame.to_local(z.lat, z.lon)
            zones.append(LocalCircle(x=x, y=y, radius=z.radius))
    inclusion = ring(area.inclusion)
    return LocalArea(
        source=area.source, origin=origin, inclusion=inclusion, nofly=tuple(zones), notes=area.notes
    )


# -- reading and validation ------------------------------------------------------------------------


def read_area(path: str | Path) -> Area:
    """The area in the file at `path` (.plan, GeoJSON or KML, told apart by content), validated."""
    p = Path(path)
    try:
        if p.stat().st_size > MAX_FILE_BYTES:
            raise MissionError(str(p), "(file)", f"larger than {MAX_FILE_BYTES:,} bytes")
        data = p.read_bytes()
    except OSError as exc:
        raise MissionError(str(p), "(file)", exc.strerror or str(exc)) from None
    return parse_area(data, str(p))


def parse_area(data: bytes, source: str) -> Area:
    """The area in a file's bytes (.plan, GeoJSON or KML, told apart by content), validated.

    `source` names the file in errors."""
    if len(data) > MAX_FILE_BYTES:
        raise MissionError(source, "(file)", f"{len(data):,} bytes; at most {MAX_FILE_BYTES:,}")
    return _validate(read_found(data, source), source)


HINTS = {
    "QGroundControl plan": "draw an inclusion polygon in the plan's GeoFence",
    "GeoJSON": 'give a Polygon (or a Feature without "nofly": true)',
    "KML": 'give a Placemark with a Polygon (not named "no-fly...")',
}


def _validate(found: Found, source: str) -> Area:
    """What a file holds as an `Area`, each ring and zone checked.

    An error names the file and the field, "area" or "area.nofly[i]" (zones in file order)."""
    if found.inclusion is None:
        raise MissionError(source, "area", f"no inclusion area: {HINTS[found.kind]}")
    if len(found.nofly) > MAX_ZONES:
        raise MissionError(source, "area.nofly", f"{len(found.nofly)} no-fly zones; at most {MAX_ZONES}")
    zones: list[ZonePolygon | ZoneCircle] = []
    for i, zone in enumerate(found.nofly):
        field = f"area.nofly[{i}]"
        if isinstance(zone, list):
            zones.append(ZonePolygon(ring=_clean_ring(zone, source, field)))
            continue
        _check_position(zone.lat, zone.lon, source, field, "the centre")
        if not (math.isfinite(zone.radius) and zone.radius > 0):
            raise MissionError(source, field, f"a circle's radius must be positive metres, got {zone.radius}")
        zones.append(ZoneCircle(lat=zone.lat, lon=zone.lon, radius=zone.radius))
    inclusion = _clean_ring(found.inclusion, source, "area")
    area = Area(source=source, kind=found.kind, inclusion=inclusion, nofly=tuple(zones))
    return msgspec.structs.replace(area, notes=(*found.notes, *_check_local(area)))


def _check_position(lat: float, lon: float, source: str, field: str, which: str) -> None:
    """A finite latitude within ±90 (else swapped?) and longitude within ±180."""
    if not (math.isfinite(lat) and math.isfinite(lon)):
        raise MissionError(source, field, f"{which} is not a finite latitude and longitude")
    if abs(lat) > 90:
        raise MissionError(
            source,
            field,
            f"{which} has latitude {lat:g}, beyond ±90: latitude and longitude swapped? "
            "(a .plan gives latitude first; GeoJSON and KML give longitude first)",
        )
    if abs(lon) > 180:
        raise MissionError(source, field, f"{which} has longitude {lon:g}, beyond ±180")


def _clean_ring(points: Sequence[LatLon], source: str, field: str) -> tuple[LatLon, ...]:
    """A ring checked (positions, vertex count, no crossing, an area) and normalised.

    Normalised: open, without repeated vertices, counter-clockwise, from its southernmost (then
    westernmost) vertex."""
    for i, (lat, lon) in enumerate(points):
        _check_position(lat, lon, source, field, f"vertex {i}")
    ring = [p for i, p in enumerate(points) if i == 0 or p != points[i - 1]]
    if len(ring) > 1 and ring[0] == ring[-1]:
        ring.pop()
    if len(ring) < 3:
        raise MissionError(source, field, f"{len(ring)} distinct vertices; a polygon needs at least 3")
    if len(ring) > MAX_VERTICES:
        raise MissionError(source, field, f"{len(ring)} vertices; at most {MAX_VERTICES}")
    shape = Polygon([(lon, lat) for lat, lon in ring])
    if shapely.MultiPoint(shape.exterior.coords).convex_hull.area == 0:
        raise MissionError(source, field, "encloses no area (its vertices are collinear)")
    if not shape.is_valid:
        where = re.search(r"\[(\S+) (\S+)\]", explain_validity(shape))
        near = f" near latitude {float(where[2]):.7f}, longitude {float(where[1]):.7f}" if where else ""
        raise MissionError(source, field, f"the ring crosses itself{near}")
    if not shapely.is_ccw(shape.exterior):
        ring.reverse()
    start = min(range(len(ring)), key=lambda i: ring[i])
    return tuple(ring[start:] + ring[:start])


def _check_local(area: Area) -> list[str]:
    """The checks in metres around the area's own origin (its size, each zone against it); notes.

    A zone wholly outside the area is kept, with a note."""
    local = local_area(area)
    polygon, source, notes = local.polygon, area.source, []
    if polygon.area < MIN_AREA_M2:
        raise MissionError(source, "area", f"encloses {polygon.area:.3g} m^2: degenerate (a sliver)")
    x0, y0, x1, y1 = polygon.bounds
    if (x1 - x0) * (y1 - y0) > MAX_AREA_M2:
        raise MissionError(
            source,
            "area",
            f"its bounding box is {(x1 - x0) / 1e3:.1f} km x {(y1 - y0) / 1e3:.1f} km; at most "
            f"{MAX_AREA_M2 / 1e6:g} km^2 (the search grid's {MAX_GRID_CELLS:,} cells of {AREA_CELL_M:g} m)",
        )
    for i, shape in enumerate(local.zone_shapes()):
        field = f"area.nofly[{i}]"
        if shape.area < MIN_AREA_M2:
            raise MissionError(source, field, f"encloses {shape.area:.3g} m^2: degenerate (a sliver)")
        if shape.covers(polygon):
            raise MissionError(source, field, "covers the whole area")
        if shape.disjoint(polygon):
            notes.append(f"{field}: wholly outside the area (kept: it still fences the aircraft)")
    if local.free.area < MIN_AREA_M2:
        raise MissionError(source, "area.nofly", "the no-fly zones together cover the whole area")
    return notes
