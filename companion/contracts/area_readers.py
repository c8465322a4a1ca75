"""Area files read into what they hold, before validation: QGroundControl .plan, GeoJSON, KML.

`read_found` tells the format from the content and returns a `Found`: the inclusion ring and the
no-fly polygons and circles in (lat, lon), in file order, and notes on what it ignored. Problems
with the file's form are `MissionError`s naming the place in the file (a JSON path, a Placemark);
`companion.contracts.areas` checks the geometry. Conventions: docs/mission-files.md.
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Iterator
from typing import Any, NamedTuple

import fastkml
import msgspec
from fastkml.utils import find_all
from lxml import etree

from companion.contracts.mission import MissionError

LatLon = tuple[float, float]  # (latitude, longitude), degrees
NOFLY_NAME = re.compile(r"\s*no[\s_-]?fly\b", re.IGNORECASE)
TRUE_WORDS = ("true", "1", "yes")
# What fastkml and pygeoif raise on malformed KML besides their own errors (a bad coordinate count)
MALFORMED = (TypeError, ValueError, AttributeError, IndexError)


class Circle(NamedTuple):
    """A no-fly circle: centre (lat, lon) in degrees, radius in metres."""

    lat: float
    lon: float
    radius: float


@dataclasses.dataclass
class Found:
    """What a file holds, before validation: `nofly` in file order (a polygon is a list of (lat, lon))."""

    kind: str  # "QGroundControl plan", "GeoJSON" or "KML"
    inclusion: list[LatLon] | None = None
    nofly: list[list[LatLon] | Circle] = dataclasses.field(default_factory=list)
    notes: list[str] = dataclasses.field(default_factory=list)


def read_found(data: bytes, source: str) -> Found:
    """What a file's bytes hold (.plan, GeoJSON or KML, told apart by content); `source` names it."""
    head = data.lstrip()[:1]
    if data[:2] == b"PK":
        raise MissionError(source, "(file)", "a zip archive (KMZ?): unzip it and give its .kml file")
    if head == b"<":
        return _parse_kml(data, source)
    if head in (b"{", b"["):
        return _parse_json(data, source)
    raise MissionError(source, "(file)", "neither JSON (a .plan or GeoJSON) nor XML (KML)")


def _parse_json(data: bytes, source: str) -> Found:
    """A JSON file: a QGroundControl plan ("fileType": "Plan") or GeoJSON (a "type")."""
    try:
        doc = msgspec.json.decode(data)
    except msgspec.DecodeError as exc:
        raise MissionError(source, "(syntax)", str(exc)) from None
    if isinstance(doc, dict) and doc.get("fileType") == "Plan":
        return _parse_plan(doc, source)
    if isinstance(doc, dict) and isinstance(doc.get("type"), str):
        parsed = Found(kind="GeoJSON")
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
    """geoFence.polygons[i]: an inclusion or exclusion polygon."""

    polygon: list[tuple[float, float]]  # (lat, lon)
    inclusion: bool


class _PlanCircleShape(msgspec.Struct):
    """geoFence.circles[i].circle."""

    center: tuple[float, float]  # (lat, lon)
    radius: float


class _PlanCircle(msgspec.Struct):
    """geoFence.circles[i]: an inclusion or exclusion circle."""

    circle: _PlanCircleShape
    inclusion: bool


class _PlanFence(msgspec.Struct):
    """A plan's geoFence (version 2)."""

    polygons: list[_PlanPolygon] = []
    circles: list[_PlanCircle] = []


class _Plan(msgspec.Struct):
    """The parts of a plan the reader reads or notes."""

    geoFence: _PlanFence | None = None  # the plan's own keys
    mission: dict[str, Any] = {}
    rallyPoints: dict[str, Any] = {}


def _parse_plan(doc: dict[str, Any], source: str) -> Found:
    """A .plan's first inclusion polygon and its exclusion polygons and circles."""
    plan = _convert(doc, _Plan, source, "")
    parsed = Found(kind="QGroundControl plan")
    fence = plan.geoFence or _PlanFence()
    for i, poly in enumerate(fence.polygons):
        if not poly.inclusion:
            parsed.nofly.append(list(poly.polygon))
        elif parsed.inclusion is None:
            parsed.inclusion = list(poly.polygon)
        else:
            parsed.notes.append(f"geoFence.polygons[{i}]: a further inclusion polygon, ignored")
    for i, c in enumerate(fence.circles):
        if c.inclusion:
            parsed.notes.append(f"geoFence.circles[{i}]: an inclusion circle, ignored")
        else:
            lat, lon = c.circle.center
            parsed.nofly.append(Circle(lat, lon, c.circle.radius))
    items = plan.mission.get("items")
    if isinstance(items, list) and items:
        parsed.notes.append(f"mission: {_count(len(items), 'mission item')}, ignored (the companions fly)")
    points = plan.rallyPoints.get("points")
    if isinstance(points, list) and points:
        parsed.notes.append(f"rallyPoints: {_count(len(points), 'rally point')}, ignored")
    return parsed


def _count(n: int, noun: str) -> str:
    """ "1 item", "2 items"."""
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
    """`value`, checked to be a GeoJSON geometry object."""
    if not isinstance(value, dict) or not isinstance(value.get("type"), str):
        raise MissionError(source, at, 'not a GeoJSON geometry (an object with a "type")')
    return value


def _flag(value: object) -> bool:
    """A no-fly flag's value: true, 1, "true", "yes" (any case)."""
    return value is True or value == 1 or (isinstance(value, str) and value.strip().lower() in TRUE_WORDS)


def _take(parsed: Found, source: str, where: str, geometry: dict[str, Any], props: dict[str, Any]) -> None:
    """Add one (lon, lat) geometry found at `where` to what the file holds.

    A Polygon's outer ring is the area (the first such) or a no-fly zone, its holes no-fly zones; a
    MultiPolygon's parts each so; a no-fly Point with a radius is a no-fly circle."""
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
    elif kind in ("Point", "MultiPoint") and nofly:
        radius = props.get("radius")
        if isinstance(radius, bool) or not isinstance(radius, int | float):
            raise MissionError(source, label, f'a no-fly point needs a "radius" in metres, got {radius!r}')
        points = [coords] if kind == "Point" else coords
        for lon, lat in (_lonlat(p, source, at) for p in _convert(points, list[list[float]], source, at)):
            parsed.nofly.append(Circle(lat, lon, float(radius)))
        return
    else:
        parsed.notes.append(f"{label}: a {kind}, not a polygon (nor a no-fly point with a radius), ignored")
        return
    for rings in polygons:
        if not rings:
            raise MissionError(source, at, "a polygon without rings")
        outer, holes = [_lonlat(p, source, at) for p in rings[0]], rings[1:]
        if nofly:
            parsed.nofly.append([(lat, lon) for lon, lat in outer])
            if holes:
                parsed.notes.append(f"{label}: the holes of a no-fly polygon, ignored")
            continue
        if parsed.inclusion is not None:
            parsed.notes.append(f"{label}: a further area polygon, ignored")
            continue
        parsed.inclusion = [(lat, lon) for lon, lat in outer]
        for hole in holes:
            ring = [_lonlat(p, source, at) for p in hole]
            parsed.nofly.append([(lat, lon) for lon, lat in ring])


def _lonlat(position: list[float], source: str, where: str) -> tuple[float, float]:
    """A GeoJSON/KML position's (lon, lat); a third number (altitude) is dropped."""
    if len(position) < 2:
        raise MissionError(source, where, f"a position needs longitude and latitude, got {position}")
    return position[0], position[1]


def _parse_kml(data: bytes, source: str) -> Found:
    """A KML's Placemarks: the no-fly ones zones, the first other polygon the area.

    No-fly: a name starting "no-fly" (or "nofly", "no fly"), or ExtendedData nofly = true; the
    area's inner boundaries are zones too."""
    parser = etree.XMLParser(resolve_entities=False, no_network=True)
    try:
        root = etree.fromstring(data, parser)
        ns = root.tag[: -len("kml")] if root.tag.endswith("kml") else ""
        names = {**fastkml.config.NAME_SPACES, "kml": ns}
        document = fastkml.KML.class_from_element(ns=ns, name_spaces=names, strict=True, element=root)
    except (etree.XMLSyntaxError, fastkml.exceptions.FastKMLError, *MALFORMED) as exc:
        reason = str(exc).splitlines()[0] if str(exc) else repr(exc)
        raise MissionError(source, "(syntax)", f"not readable as KML: {reason}") from None
    parsed = Found(kind="KML")
    placemarks = [
        p for p in find_all(document, of_type=fastkml.Placemark) if isinstance(p, fastkml.Placemark)
    ]
    for i, placemark in enumerate(placemarks):
        where = f"Placemark {i}" + (f" ({placemark.name!r})" if placemark.name else "")
        try:  # pygeoif builds the geometry on access, and fails on a malformed one as it may
            geometry = placemark.geometry
            shape = None if geometry is None else dict(geometry.__geo_interface__)
        except MALFORMED as exc:
            raise MissionError(source, where, f"a malformed geometry ({exc})") from None
        if shape is None:
            parsed.notes.append(f"{where}: no (readable) geometry, ignored")
            continue
        data_items = placemark.extended_data.elements if placemark.extended_data else []
        extended = {d.name: d.value for d in data_items if isinstance(d, fastkml.Data)}
        nofly = _flag(extended.get("nofly")) or bool(NOFLY_NAME.match(placemark.name or ""))
        props = {"nofly": nofly, "radius": _kml_number(extended.get("radius"))}
        for part in _parts(shape):
            _take(parsed, source, where, part, props)
    return parsed


def _parts(shape: dict[str, Any]) -> Iterator[dict[str, Any]]:
    """The geometries in a KML geometry: a MultiGeometry of mixed parts (nested or not) part by part."""
    if shape.get("type") != "GeometryCollection":
        yield shape
        return
    for part in shape.get("geometries") or ():
        yield from _parts(dict(part))


def _kml_number(text: str | None) -> float | str | None:
    """An ExtendedData value as a number when it is one (else as given, for the error)."""
    try:
        return float(text) if text is not None else None
    except ValueError:
        return text
