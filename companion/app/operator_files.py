"""Files for the operator: a run's tracks, sectors and detections as GeoJSON, KML and a QGC plan.

`export` writes a `Picture` (`companion.app.operator_run`) as `operator.geojson` (RFC 7946, lon/lat),
`operator.kml` (Folders of Placemarks, a style per UAV) and `sectors.plan` (QGroundControl's plan:
the region and each sector as geofence inclusion polygons, the no-fly zones as exclusions). Each
file opens with the mission's region and marks its zones, so the project's own area reader
(`companion.contracts.areas`) reads any of them as that area. Layers, properties and the plan's
caveats: docs/companion.md, "Files for the operator".
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import fastkml
import numpy as np
import pygeoif
import shapely
from fastkml import styles
from shapely.geometry import LineString, MultiPolygon, Point, Polygon, mapping
from shapely.geometry.polygon import orient

from companion.app.operator_run import Detection, Picture, Sector, Track
from companion.contracts.frames import LocalFrame
from companion.contracts.mission import NoFlyCircle
from companion.core.search_area import zone_shape

FORMATS = ("geojson", "kml", "plan")
FILES = {"geojson": "operator.geojson", "kml": "operator.kml", "plan": "sectors.plan"}
NOFLY_RGB = "#d62728"  # the no-fly zones' red
DECIMALS = 7  # 1e-7 degree, about a centimetre: MAVLink's resolution
PALETTE = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#bcbd22", "#17becf")
UNHELD = "#7f7f7f"  # the sectors no UAV held
FIRMWARE = {"ardupilot": 3, "px4": 12}  # MAV_AUTOPILOT of the plan's mission
FIXED_WING = 1  # MAV_TYPE_FIXED_WING
ICON = "https://maps.google.com/mapfiles/kml/shapes/placemark_circle.png"  # Google Earth's own


def colour(uav: int | None) -> str:
    """A UAV's colour, #rrggbb (grey for what no UAV held)."""
    return UNHELD if uav is None else PALETTE[uav % len(PALETTE)]


def geodetic(frame: LocalFrame) -> Callable[[shapely.Geometry], shapely.Geometry]:
    """A function taking a shape in local metres to (lon, lat) degrees, rounded to 1e-7.

    Polygons come out counter-clockwise, holes clockwise, as RFC 7946 and KML ask."""

    def to_lonlat(points: np.ndarray) -> np.ndarray:
        """(n, 2) local metres as (n, 2) (lon, lat)."""
        lat, lon = frame.cells_to_geodetic(points)
        return np.column_stack([lon, lat]).round(DECIMALS)

    def convert(shape: shapely.Geometry) -> shapely.Geometry:
        """The shape in (lon, lat), its polygons oriented."""
        shape = shapely.transform(shape, to_lonlat)
        if isinstance(shape, Polygon):
            return orient(shape, 1.0)
        if isinstance(shape, MultiPolygon):
            return MultiPolygon([orient(p, 1.0) for p in shape.geoms])
        return shape

    return convert


def _track_line(track: Track) -> LineString:
    """A track's points as a line (a one-point track repeats its point)."""
    points = track.points if len(track.points) > 1 else np.vstack([track.points, track.points])
    return LineString(points)


def _sector_name(sector: Sector) -> str:
    """A sector's Placemark name."""
    return f"sector of UAV {sector.uav}" if sector.uav is not None else "tasks held by no UAV"


def _properties(picture: Picture) -> list[tuple[str, shapely.Geometry, dict[str, Any]]]:
    """(name, shape in metres, properties) of every feature: region, sectors, tracks, detections."""
    m, step_s = picture.mission, picture.mission.kinematics.step
    out: list[tuple[str, shapely.Geometry, dict[str, Any]]] = [
        (f"{m.name}: search region", picture.region, {"layer": "region", "mission": m.name})
    ]
    for i, z in enumerate(m.region.nofly):
        kind = "circle" if isinstance(z, NoFlyCircle) else "polygon"
        zone: dict[str, Any] = {"layer": "nofly", "nofly": True, "zone": i, "kind": kind}
        zone |= {"radius_m": z.radius} if isinstance(z, NoFlyCircle) else {}
        out.append((f"no-fly zone {i}", zone_shape(z), zone))
    for s in picture.sectors:
        sector: dict[str, Any] = {"layer": "sector", "uav": s.uav, "tasks": list(s.tasks), "cells": s.cells}
        out.append((_sector_name(s), s.shape, sector | {"area_m2": round(s.shape.area, 1)}))
    for t in picture.tracks:
        track: dict[str, Any] = {"layer": "track", "uav": t.uav, "altitude_m": t.altitude}
        track |= {"altitude_amsl_m": m.region.origin.alt + t.altitude}
        track |= {"steps": len(t.points), "step_s": step_s}
        out.append((f"track of UAV {t.uav}", _track_line(t), track))
    for d in picture.detections:
        found: dict[str, Any] = {"layer": "detection", "cell": d.cell, "step": d.step}
        found |= {"time_s": None if d.step is None else d.step * step_s, "uav": d.uav, "true": d.true}
        out.append((_detection_name(d), Point(d.x, d.y), found))
    return out


def _detection_name(d: Detection) -> str:
    """A detection's Placemark name: its cell, step, and (flown runs) if false."""
    truth = " (false)" if d.true is False else ""
    when = "" if d.step is None else f" at step {d.step}"
    return f"target in cell {d.cell}{when}{truth}"


def _meta(picture: Picture) -> dict[str, Any]:
    """What run the files show: mission, algorithm, run, seed, origin, and the notes."""
    o = picture.mission.region.origin
    return {
        "mission": picture.mission.name,
        "algorithm": picture.algorithm,
        "run": picture.run,
        "seed": picture.seed,
        "flown": picture.flown,
        "origin": {"lat": o.lat, "lon": o.lon, "alt": o.alt},
        "notes": picture.notes,
    }


def geojson(picture: Picture) -> dict[str, Any]:
    """The run as an RFC 7946 FeatureCollection (lon, lat; polygons counter-clockwise).

    Each feature's `layer` is region, sector, track or detection; simplestyle `stroke`/`fill`
    colour it per UAV; the foreign member `uavsearch` names the run."""
    to_lonlat = geodetic(LocalFrame(picture.mission.region.origin))
    features = []
    for name, shape, props in _properties(picture):
        shape = to_lonlat(shape)
        layer = props["layer"]
        rgb = {"region": "#000000", "nofly": NOFLY_RGB}.get(layer) or colour(props.get("uav"))
        style: dict[str, Any] = {"stroke": rgb}
        if layer in ("region", "sector", "nofly"):
            style |= {"fill": rgb, "fill-opacity": {"region": 0.0, "sector": 0.25}.get(layer, 0.4)}
        features.append(
            {"type": "Feature", "geometry": mapping(shape), "properties": {"name": name, **props, **style}}
        )
    return {"type": "FeatureCollection", "features": features, "uavsearch": _meta(picture)}


def _kml_colour(rgb: str, alpha: int) -> str:
    """#rrggbb as KML's aabbggrr."""
    return f"{alpha:02x}{rgb[5:7]}{rgb[3:5]}{rgb[1:3]}"


def _kml_styles(picture: Picture) -> list[styles.Style]:
    """A style a UAV (and one for what no UAV held): its line, a translucent fill, its icon; the region's."""
    looks = [(_style_id(uav), colour(uav), 0x40) for uav in [*range(picture.mission.n_uavs), None]]
    return [
        styles.Style(
            id=style_id,
            styles=[
                styles.LineStyle(color=_kml_colour(rgb, 0xFF), width=3),
                styles.PolyStyle(color=_kml_colour(rgb, fill)),
                styles.IconStyle(color=_kml_colour(rgb, 0xFF), icon=styles.Icon(href=ICON)),
            ],
        )
        for style_id, rgb, fill in [*looks, ("region", "#000000", 0), ("nofly", NOFLY_RGB, 0x66)]
    ]


def _style_id(uav: int | None, layer: str = "") -> str:
    """A Placemark's style: its UAV's (the region's and the no-fly zones' own)."""
    if layer in ("region", "nofly"):
        return layer
    return "unheld" if uav is None else f"uav{uav}"


def kml(picture: Picture) -> fastkml.KML:
    """The run as KML: a Document with Folders (region, sectors, tracks, detections) of Placemarks.

    Every property is the Placemark's ExtendedData; its style is its UAV's."""
    to_lonlat = geodetic(LocalFrame(picture.mission.region.origin))
    layers = ("region", "nofly", "sector", "track", "detection")
    folders: dict[str, list[fastkml.Placemark]] = {layer: [] for layer in layers}
    for name, shape, props in _properties(picture):
        data = [fastkml.Data(name=k, value=_text(v)) for k, v in props.items()]
        folders[props["layer"]].append(
            fastkml.Placemark(
                name=name,
                style_url=styles.StyleUrl(url=f"#{_style_id(props.get('uav'), props['layer'])}"),
                extended_data=fastkml.ExtendedData(elements=data),
                geometry=pygeoif.shape(to_lonlat(shape)),
            )
        )
    titles = {"region": "Search region", "nofly": "No-fly zones", "sector": "Sectors", "track": "Tracks"}
    titles["detection"] = "Detections"
    document = fastkml.Document(
        name=f"{picture.mission.name}: {picture.algorithm} run {picture.run}",
        description=json.dumps(_meta(picture)),
        styles=_kml_styles(picture),
        features=[
            fastkml.Folder(name=titles[k], features=v) for k, v in folders.items() if v or k != "nofly"
        ],
    )
    return fastkml.KML(features=[document])


def _text(value: object) -> str:
    """A property as ExtendedData text: JSON for lists and None, else str."""
    return json.dumps(value) if isinstance(value, list | type(None) | bool) else str(value)


def _ring(polygon: Polygon, frame: LocalFrame) -> list[list[float]]:
    """A polygon's outer ring as a plan's open list of [lat, lon]."""
    coords = np.asarray(orient(polygon, 1.0).exterior.coords)[:-1]
    lat, lon = frame.cells_to_geodetic(coords)
    return np.column_stack([lat, lon]).round(DECIMALS).tolist()


def plan(picture: Picture) -> dict[str, Any]:
    """The sectors as a QGroundControl plan: the region, then each sector's parts, as inclusion polygons.

    A plan's polygon has no holes: a sector's holes (other sectors inside it) are left out."""
    m = picture.mission
    frame, o = LocalFrame(m.region.origin), m.region.origin
    polygons = [_ring(picture.region, frame)]
    polygons += [_ring(p, frame) for s in picture.sectors for p in s.shape.geoms]
    fence = [{"inclusion": True, "polygon": p, "version": 1} for p in polygons]
    circles = []
    for z in m.region.nofly:  # the operator's zones as exclusions, as drawn
        if isinstance(z, NoFlyCircle):
            lat, lon = frame.to_geodetic(z.x, z.y)[:2]
            centre = [round(lat, DECIMALS), round(lon, DECIMALS)]
            circle = {"center": centre, "radius": z.radius}
            circles.append({"circle": circle, "inclusion": False, "version": 1})
        else:
            fence.append({"inclusion": False, "polygon": _ring(zone_shape(z), frame), "version": 1})
    return {
        "fileType": "Plan",
        "version": 1,
        "groundStation": "QGroundControl",
        "mission": {
            "version": 2,
            "firmwareType": FIRMWARE[m.sim.flavour],
            "vehicleType": FIXED_WING,
            "cruiseSpeed": m.kinematics.speed,
            "hoverSpeed": 5,
            "globalPlanAltitudeMode": 1,
            "plannedHomePosition": [o.lat, o.lon, o.alt],
            "items": [],
        },
        "geoFence": {
            "version": 2,
            "circles": circles,
            "polygons": fence,
        },
        "rallyPoints": {"version": 2, "points": []},
    }


def export(picture: Picture, out: Path, formats: tuple[str, ...] = FORMATS) -> list[Path]:
    """Write the chosen files of `picture` into `out` (made if missing); returns their paths."""
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for kind in formats:
        path = out / FILES[kind]
        if kind == "kml":
            path.write_text(kml(picture).to_string(prettyprint=True) + "\n")
        else:
            doc = geojson(picture) if kind == "geojson" else plan(picture)
            path.write_text(json.dumps(doc, indent=1) + "\n")
        written.append(path)
    return written
