"""Search areas and no-fly zones from the operator's own files: QGroundControl .plan, GeoJSON, KML.

`read_area` reads one file into an `Area` (latitude/longitude, validated); `local_area` projects it
into a mission's local frame. Every problem is one `MissionError(file, field, reason)`; what the
reader ignores it returns as notes, never printed. Formats, no-fly markings, the origin rule and
the limits: docs/mission-files.md, "Areas from a ground station or GIS".
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import fastkml
import msgspec
import shapely
from fastkml.utils import find_all
from lxml import etree
from shapely.geometry import Point, Polygon
from shapely.validation import explain_validity

from companion.contracts.frames import LocalFrame
from companion.contracts.mission import MAX_FILE_BYTES, MAX_GRID_CELLS, MAX_VERTICES, MissionError, Origin

LatLon = tuple[float, float]  # (latitude, longitude), degrees
XY = tuple[float, float]  # (x east, y north), metres
AREA_CELL_M = 40.0  # the paper's cell: the area limit is MAX_GRID_CELLS of them
MAX_AREA_M2 = MAX_GRID_CELLS * AREA_CELL_M**2  # 400 km^2: the inclusion polygon's bounding box
MAX_ZONES = 64
MIN_AREA_M2 = 1.0  # a ring enclosing less is degenerate
ORIGIN_DECIMALS = 7  # the area's own origin, rounded to MAVLink's 1e-7 degree
CIRCLE_SEGMENTS = 64  # a circle's polygon (quarter-circle segments) in the coverage checks
NOFLY_NAME = re.compile(r"\s*no[\s_-]?fly\b", re.IGNORECASE)
TRUE_WORDS = ("true", "1", "yes")


class _Frozen(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True):
    pass


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
    if isinstance(zone, LocalPolygon):
        return Polygon(zone.ring)
    circumscribed = zone.radius / math.cos(math.pi / (4 * CIRCLE_SEGMENTS))  # the circle inside it
    return Point(zone.x, zone.y).buffer(circumscribed, quad_segs=CIRCLE_SEGMENTS)


def local_area(area: Area, origin: Origin | None = None) -> LocalArea:
    """`area` in the local frame around `origin` (default: the area's own, `Area.origin`)."""
    origin = origin or area.origin
    frame = LocalFrame(origin)

    def ring(points: Sequence[LatLon]) -> tuple[XY, ...]:
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


# -- reading -------------------------------------------------------------------------------------


class _Parsed(msgspec.Struct, kw_only=True):
    """What a format's reader found, before validation."""

    kind: str
    inclusion: list[LatLon] | None = None
    nofly: list[ZonePolygon | ZoneCircle] = []
    notes: list[str] = []


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
    """The area in a file's bytes; `source` names it in errors."""
    head = data.lstrip()[:1]
    if data[:2] == b"PK":
        raise MissionError(source, "(file)", "a zip archive (KMZ?): unzip it and give its .kml file")
    if head == b"<":
        parsed = _parse_kml(data, source)
    elif head in (b"{", b"["):
        parsed = _parse_json(data, source)
    else:
        raise MissionError(source, "(file)", "neither JSON (a .plan or GeoJSON) nor XML (KML)")
    return _validate(parsed, source)


def _parse_json(data: bytes, source: str) -> _Parsed:
    try:
        doc = msgspec.json.decode(data)
    except msgspec.DecodeError as exc:
        raise MissionError(source, "(syntax)", str(exc)) from None
    if isinstance(doc, dict) and doc.get("fileType") == "Plan":
        return _parse_plan(doc, source)
    if isinstance(doc, dict) and isinstance(doc.get("type"), str):
        parsed = _Parsed(kind="GeoJSON")
        for where, geometry, properties in _geojson_features(doc, source, parsed.notes):
            _take(parsed, source, where, geometry, properties)
        return parsed
    raise MissionError(
        source, "(document)", 'neither a QGroundControl plan ("fileType": "Plan") nor GeoJSON (a "type")'
    )


_MSGSPEC_AT = re.compile(r" - at `\$(?P<path>[^`]*)`$")


def _convert(value: object, kind: type[Any], source: str, where: str) -> Any:
    """`value` as `kind` (msgspec), or the MissionError naming where in the file it failed."""
    try:
        return msgspec.convert(value, kind)
    except msgspec.ValidationError as exc:
        match = _MSGSPEC_AT.search(str(exc))
        reason = str(exc)[: match.start()] if match else str(exc)
        path = match.group("path") if match else ""
        raise MissionError(source, f"{where}{path}".lstrip(".") or "(document)", reason) from None


# QGroundControl's plan (docs/mission-files.md): only what the reader uses is typed; the rest is noted.
class _PlanPolygon(msgspec.Struct):
    polygon: list[tuple[float, float]]  # (lat, lon)
    inclusion: bool


class _PlanCircleShape(msgspec.Struct):
    center: tuple[float, float]  # (lat, lon)
    radius: float


class _PlanCircle(msgspec.Struct):
    circle: _PlanCircleShape
    inclusion: bool


class _PlanFence(msgspec.Struct):
    polygons: list[_PlanPolygon] = []
    circles: list[_PlanCircle] = []


class _Plan(msgspec.Struct):
    geoFence: _PlanFence | None = None  # the plan's own keys
    mission: dict[str, Any] = {}
    rallyPoints: dict[str, Any] = {}


def _parse_plan(doc: dict[str, Any], source: str) -> _Parsed:
    """A .plan's first inclusion polygon and its exclusion polygons and circles."""
    plan = _convert(doc, _Plan, source, "")
    parsed = _Parsed(kind="QGroundControl plan")
    fence = plan.geoFence or _PlanFence()
    for i, poly in enumerate(fence.polygons):
        if not poly.inclusion:
            parsed.nofly.append(ZonePolygon(ring=tuple(poly.polygon)))
        elif parsed.inclusion is None:
            parsed.inclusion = list(poly.polygon)
        else:
            parsed.notes.append(f"geoFence.polygons[{i}]: a further inclusion polygon, ignored")
    for i, c in enumerate(fence.circles):
        if c.inclusion:
            parsed.notes.append(f"geoFence.circles[{i}]: an inclusion circle, ignored")
        else:
            lat, lon = c.circle.center
            parsed.nofly.append(ZoneCircle(lat=lat, lon=lon, radius=c.circle.radius))
    items = plan.mission.get("items")
    if isinstance(items, list) and items:
        parsed.notes.append(f"mission: {_count(len(items), 'mission item')}, ignored (the companions fly)")
    points = plan.rallyPoints.get("points")
    if isinstance(points, list) and points:
        parsed.notes.append(f"rallyPoints: {_count(len(points), 'rally point')}, ignored")
    return parsed


def _count(n: int, noun: str) -> str:
    return f"{n} {noun}" + ("" if n == 1 else "s")


def _geojson_features(
    doc: dict[str, Any], source: str, notes: list[str], at: str = ""
) -> Iterator[tuple[str, dict[str, Any], dict[str, Any]]]:
    """(where in the file, geometry, properties) of each geometry of a GeoJSON object at `at`."""
    kind = doc.get("type")
    if kind == "FeatureCollection":
        features = doc.get("features")
        if not isinstance(features, list):
            raise MissionError(source, _at(at, "features"), "a FeatureCollection needs a list of features")
        for i, feature in enumerate(features):
            if not isinstance(feature, dict) or feature.get("type") != "Feature":
                raise MissionError(source, _at(at, f"features[{i}]"), 'not a Feature ("type": "Feature")')
            yield from _geojson_features(feature, source, notes, _at(at, f"features[{i}]"))
    elif kind == "Feature":
        geometry, properties = doc.get("geometry"), doc.get("properties") or {}
        if not isinstance(properties, dict):
            raise MissionError(source, _at(at, "properties"), "must be an object or null")
        if geometry is None:
            notes.append(f"{at or 'the Feature'}: no geometry, ignored")
            return
        where = _at(at, "geometry")
        for w, g, _ in _geojson_features(_geometry(geometry, source, where), source, notes, where):
            yield w, g, properties
    elif kind == "GeometryCollection":
        members = _convert(doc.get("geometries"), list[Any], source, _at(at, "geometries"))
        for i, member in enumerate(members):
            where = _at(at, f"geometries[{i}]")
            yield from _geojson_features(_geometry(member, source, where), source, notes, where)
    else:
        yield at, doc, {}


def _at(at: str, key: str) -> str:
    """A JSON path one key deeper."""
    return f"{at}.{key}" if at else key


def _geometry(value: object, source: str, at: str) -> dict[str, Any]:
    if not isinstance(value, dict) or not isinstance(value.get("type"), str):
        raise MissionError(source, at, 'not a GeoJSON geometry (an object with a "type")')
    return value


def _flag(value: object) -> bool:
    """A no-fly flag's value: true, 1, "true", "yes" (any case)."""
    return value is True or value == 1 or (isinstance(value, str) and value.strip().lower() in TRUE_WORDS)


def _take(parsed: _Parsed, source: str, where: str, geometry: dict[str, Any], props: dict[str, Any]) -> None:
    """Add one (lon, lat) geometry found at `where`: a Polygon's outer ring is the area or a no-fly
    zone, its holes no-fly zones; a MultiPolygon's parts each so; a no-fly Point with a radius, a
    no-fly circle."""
    kind, nofly = geometry["type"], _flag(props.get("nofly"))
    coords, label, at = (
        geometry.get("coordinates"),
        where or f"the {geometry['type']}",
        _at(where, "coordinates"),
    )
    if kind == "Polygon":
        polygons = [_convert(coords, list[list[list[float]]], source, at)]
    elif kind == "MultiPolygon":
        polygons = _convert(coords, list[list[list[list[float]]]], source, at)
    elif kind == "Point" and nofly:
        lon, lat = _lonlat(_convert(coords, list[float], source, at), source, at)
        radius = props.get("radius")
        if isinstance(radius, bool) or not isinstance(radius, int | float):
            raise MissionError(source, label, f'a no-fly point needs a "radius" in metres, got {radius!r}')
        parsed.nofly.append(ZoneCircle(lat=lat, lon=lon, radius=float(radius)))
        return
    else:
        parsed.notes.append(f"{label}: a {kind}, not a polygon (nor a no-fly point with a radius), ignored")
        return
    for rings in polygons:
        if not rings:
            raise MissionError(source, at, "a polygon without rings")
        outer, holes = [_lonlat(p, source, at) for p in rings[0]], rings[1:]
        if nofly:
            parsed.nofly.append(ZonePolygon(ring=tuple((lat, lon) for lon, lat in outer)))
            if holes:
                parsed.notes.append(f"{label}: the holes of a no-fly polygon, ignored")
            continue
        if parsed.inclusion is not None:
            parsed.notes.append(f"{label}: a further area polygon, ignored")
            continue
        parsed.inclusion = [(lat, lon) for lon, lat in outer]
        for hole in holes:
            ring = [_lonlat(p, source, at) for p in hole]
            parsed.nofly.append(ZonePolygon(ring=tuple((lat, lon) for lon, lat in ring)))


def _lonlat(position: list[float], source: str, where: str) -> tuple[float, float]:
    """A GeoJSON/KML position's (lon, lat); a third number (altitude) is dropped."""
    if len(position) < 2:
        raise MissionError(source, where, f"a position needs longitude and latitude, got {position}")
    return position[0], position[1]


def _parse_kml(data: bytes, source: str) -> _Parsed:
    """A KML's Placemarks: no-fly ones (a name starting "no-fly", or ExtendedData nofly = true)
    are zones, the first other polygon is the area (its inner boundaries zones)."""
    parser = etree.XMLParser(resolve_entities=False, no_network=True)
    try:
        root = etree.fromstring(data, parser)
        ns = root.tag[: -len("kml")] if root.tag.endswith("kml") else ""
        names = {**fastkml.config.NAME_SPACES, "kml": ns}
        document = fastkml.KML.class_from_element(ns=ns, name_spaces=names, strict=True, element=root)
    except (etree.XMLSyntaxError, fastkml.exceptions.FastKMLError, ValueError) as exc:
        raise MissionError(source, "(syntax)", str(exc).splitlines()[0] if str(exc) else repr(exc)) from None
    parsed = _Parsed(kind="KML")
    placemarks = [
        p for p in find_all(document, of_type=fastkml.Placemark) if isinstance(p, fastkml.Placemark)
    ]
    for i, placemark in enumerate(placemarks):
        where = f"Placemark {i}" + (f" ({placemark.name!r})" if placemark.name else "")
        if placemark.geometry is None:
            parsed.notes.append(f"{where}: no geometry, ignored")
            continue
        data_items = placemark.extended_data.elements if placemark.extended_data else []
        extended = {d.name: d.value for d in data_items if isinstance(d, fastkml.Data)}
        nofly = _flag(extended.get("nofly")) or bool(NOFLY_NAME.match(placemark.name or ""))
        props = {"nofly": nofly, "radius": _kml_number(extended.get("radius"))}
        _take(parsed, source, where, dict(placemark.geometry.__geo_interface__), props)
    return parsed


def _kml_number(text: str | None) -> float | str | None:
    """An ExtendedData value as a number when it is one (else as given, for the error)."""
    try:
        return float(text) if text is not None else None
    except ValueError:
        return text


# -- validation ----------------------------------------------------------------------------------

HINTS = {
    "QGroundControl plan": "draw an inclusion polygon in the plan's GeoFence",
    "GeoJSON": 'give a Polygon (or a Feature without "nofly": true)',
    "KML": 'give a Placemark with a Polygon (not named "no-fly...")',
}


def _validate(parsed: _Parsed, source: str) -> Area:
    """`parsed` as an `Area`, each ring and zone checked (module docstring: every error names the
    file and the field, "area" or "area.nofly[i]")."""
    if parsed.inclusion is None:
        raise MissionError(source, "area", f"no inclusion area: {HINTS[parsed.kind]}")
    if len(parsed.nofly) > MAX_ZONES:
        raise MissionError(source, "area.nofly", f"{len(parsed.nofly)} no-fly zones; at most {MAX_ZONES}")
    zones: list[ZonePolygon | ZoneCircle] = []
    for i, zone in enumerate(parsed.nofly):
        field = f"area.nofly[{i}]"
        if isinstance(zone, ZonePolygon):
            zones.append(ZonePolygon(ring=_clean_ring(zone.ring, source, field)))
            continue
        _check_position(zone.lat, zone.lon, source, field, "the centre")
        if not (math.isfinite(zone.radius) and zone.radius > 0):
            raise MissionError(source, field, f"a circle's radius must be positive metres, got {zone.radius}")
        zones.append(zone)
    inclusion = _clean_ring(parsed.inclusion, source, "area")
    area = Area(source=source, kind=parsed.kind, inclusion=inclusion, nofly=tuple(zones))
    return msgspec.structs.replace(area, notes=(*parsed.notes, *_check_local(area)))


def _check_position(lat: float, lon: float, source: str, field: str, which: str) -> None:
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
    """A ring checked (positions, vertex count, no crossing, an area) and normalised: open, without
    repeated vertices, counter-clockwise, from its southernmost (then westernmost) vertex."""
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
    """The checks in metres, around the area's own origin: its size, and each zone against it;
    returns the notes (a zone wholly outside the area)."""
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
            f"{MAX_AREA_M2 / 1e6:g} km^2 (MAX_GRID_CELLS cells of {AREA_CELL_M:g} m)",
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
