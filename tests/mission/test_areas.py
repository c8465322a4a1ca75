"""Areas from the operator's files (companion/contracts/areas.py): one area as a .plan, GeoJSON or KML
gives one `Area`; every bad file gets one line naming the file and the reason; `uavsearch area`."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.cli.main import main
from companion.contracts.areas import (
    MAX_ZONES,
    LocalArea,
    LocalCircle,
    LocalPolygon,
    ZoneCircle,
    local_area,
    parse_area,
    read_area,
)
from companion.contracts.frames import LocalFrame
from companion.contracts.mission import MAX_FILE_BYTES, MAX_VERTICES, MissionError, Origin
from companion.contracts.mission_file import read_schema

ROOT = Path(__file__).resolve().parents[2]
HERE = Path(__file__).parent / "areas"
SHIPPED = ROOT / "mission_files" / "areas"
SCENARIO1 = read_schema(ROOT / "mission_files" / "scenario1.toml").region
BAND = [(-450.0, 200.0), (450.0, 260.0), (450.0, 410.0), (-450.0, 350.0)]  # the no-fly band, local m
TWINS = [
    SHIPPED / "scenario1_nofly.plan",
    SHIPPED / "scenario1_nofly.geojson",
    SHIPPED / "scenario1_nofly.kml",
    HERE / "scenario1_hole.geojson",  # the band as the polygon's hole
    HERE / "scenario1_inner.kml",  # ... as the polygon's inner boundary
    HERE / "scenario1_named.kml",  # ... as a placemark named "no-fly: ..."
]
CM = 0.01


def _close(
    a: tuple[tuple[float, float], ...], b: list[tuple[float, float]] | tuple[tuple[float, float], ...]
) -> bool:
    return len(a) == len(b) and all(math.dist(p, q) < CM for p, q in zip(a, b, strict=True))


def test_one_area_in_every_format_gives_the_same_area() -> None:
    first = read_area(TWINS[0])
    assert first.notes == () and len(first.nofly) == 1
    own = local_area(first)
    for path in TWINS[1:]:
        area = read_area(path)
        assert area.origin == first.origin, path
        local = local_area(area)
        assert _close(local.inclusion, own.inclusion), path
        assert len(local.nofly) == 1 and isinstance(local.nofly[0], LocalPolygon), path
        assert isinstance(own.nofly[0], LocalPolygon)
        assert _close(local.nofly[0].ring, own.nofly[0].ring), path
        assert area.notes == (), path


@pytest.mark.parametrize("path", TWINS, ids=lambda p: p.name)
def test_the_area_is_scenario_1s_region_with_the_band(path: Path) -> None:
    local = local_area(read_area(path), SCENARIO1.origin)
    assert _close(local.inclusion, [tuple(p) for p in SCENARIO1.polygon])  # scenario 1 is counter-clockwise
    zone = local.nofly[0]
    assert isinstance(zone, LocalPolygon) and _close(zone.ring, BAND)
    assert local.polygon.area == pytest.approx(4e6, abs=1.0)
    assert local.free.area == pytest.approx(4e6 - 135_000, abs=1.0)


def test_the_areas_own_origin_is_its_centroid() -> None:
    area = read_area(TWINS[0])
    o = SCENARIO1.origin
    assert abs(area.origin.lat - o.lat) < 1e-6 and abs(area.origin.lon - o.lon) < 1e-6
    assert area.origin.alt == 0.0
    assert local_area(area).origin == area.origin


BAD = [
    ("garbled.plan", "(syntax)", "truncated"),
    ("garbled.kml", "(syntax)", "invalid element name"),
    ("no_inclusion.plan", "area", "no inclusion area"),
    ("no_inclusion.geojson", "area", "no inclusion area"),
    ("empty.plan", "area", "0 distinct vertices"),
    ("degenerate.geojson", "area", "degenerate"),
    ("crossing.kml", "area", "crosses itself"),
    ("swapped.geojson", "area", "latitude and longitude swapped"),
    ("swapped.plan", "area", "latitude and longitude swapped"),
    ("zone_covers.plan", "area.nofly[0]", "covers the whole area"),
    ("circle_covers.plan", "area.nofly[0]", "covers the whole area"),
    ("zones_cover.plan", "area.nofly", "together cover the whole area"),
    ("too_large.geojson", "area", "at most 400 km^2"),
]


@pytest.mark.parametrize(("name", "field", "reason"), BAD, ids=[b[0] for b in BAD])
def test_a_bad_file_is_one_line_naming_it(
    name: str, field: str, reason: str, capsys: pytest.CaptureFixture[str]
) -> None:
    path = HERE / name
    with pytest.raises(MissionError) as err:
        read_area(path)
    assert (err.value.source, err.value.field) == (str(path), field) and reason in err.value.reason
    assert main(["area", str(path)]) == 2
    out, errors = capsys.readouterr()
    assert out == "" and errors == f"error: area file {path}: {field}: {err.value.reason}\n"


def _polygon_geojson(points: list[tuple[float, float]], origin: Origin) -> bytes:
    frame = LocalFrame(origin)
    ring = [list(reversed(frame.to_geodetic(x, y)[:2])) for x, y in points]
    return json.dumps({"type": "Polygon", "coordinates": [[*ring, ring[0]]]}).encode()


def _star(n: int, radius: float) -> list[tuple[float, float]]:
    return [
        (radius * math.cos(2 * math.pi * i / n), radius * math.sin(2 * math.pi * i / n)) for i in range(n)
    ]


def test_too_many_vertices() -> None:
    data = _polygon_geojson(_star(MAX_VERTICES + 1, 1000.0), SCENARIO1.origin)
    with pytest.raises(MissionError, match=f"{MAX_VERTICES + 1} vertices; at most {MAX_VERTICES}"):
        parse_area(data, "many.geojson")


def test_too_many_zones() -> None:
    area = json.loads(_polygon_geojson(_star(4, 1000.0), SCENARIO1.origin))
    holes = [json.loads(_polygon_geojson(_star(3, 5.0), SCENARIO1.origin))["coordinates"][0]]
    area["coordinates"] += holes * (MAX_ZONES + 1)
    with pytest.raises(MissionError) as err:
        parse_area(json.dumps(area).encode(), "zones.geojson")
    assert err.value.field == "area.nofly" and f"at most {MAX_ZONES}" in err.value.reason


@pytest.mark.parametrize(
    ("data", "field", "reason"),
    [
        (b"PK\x03\x04...", "(file)", "KMZ"),
        (b"hello", "(file)", "neither JSON"),
        (b" " * (MAX_FILE_BYTES + 1), "(file)", "at most"),
        (b'{"fileType": "Mission"}', "(document)", "neither a QGroundControl plan"),
        (
            b'{"fileType": "Plan", "geoFence": {"polygons": [{"polygon": [[1, 2]]}]}}',
            "geoFence.polygons[0]",
            "missing required field `inclusion`",
        ),
        (b'{"type": "Polygon", "coordinates": [[[1, "x"]]]}', "coordinates[0][0][1]", "float"),
        (
            b'{"type": "FeatureCollection", "features": [{"type": "Feature", "properties": null, '
            b'"geometry": {"type": "GeometryCollection", "geometries": [5]}}]}',
            "features[0].geometry.geometries[0]",
            "not a GeoJSON geometry",
        ),
        (b'{"type": "Point", "coordinates": [149.1, -35.3]}', "area", "no inclusion area"),
        (
            b'<kml xmlns="http://www.opengis.net/kml/2.2"><Placemark><Polygon><outerBoundaryIs>'
            b"<LinearRing><coordinates>149.1 149.2</coordinates></LinearRing></outerBoundaryIs>"
            b"</Polygon></Placemark></kml>",
            "(syntax)",
            "not readable as KML",
        ),
        (
            b'<kml xmlns="http://www.opengis.net/kml/2.2"><Placemark><name>x</name>'
            b"<Point><coordinates>nan,inf</coordinates></Point></Placemark></kml>",
            "Placemark 0 ('x')",
            "a malformed geometry",
        ),
    ],
)
def test_malformed_content_names_the_place(data: bytes, field: str, reason: str) -> None:
    with pytest.raises(MissionError) as err:
        parse_area(data, "f")
    assert err.value.field == field and reason in err.value.reason


def test_a_missing_file() -> None:
    with pytest.raises(MissionError) as err:
        read_area(HERE / "no_such_file.plan")
    assert err.value.field == "(file)"


def test_what_is_ignored_comes_back_as_notes() -> None:
    area = read_area(HERE / "with_extras.plan")
    notes = "\n".join(area.notes)
    for part in (
        "polygons[1]: a further inclusion",
        "circles[0]: an inclusion circle",
        "1 mission item",
        "1 rally",
    ):
        assert part in notes
    assert "area.nofly[0]: wholly outside the area" in notes
    assert len(area.nofly) == 2 and isinstance(area.nofly[1], ZoneCircle)


def test_no_fly_points_with_a_radius_are_circles_in_geojson_and_kml() -> None:
    frame = LocalFrame(SCENARIO1.origin)
    lat, lon, _ = frame.to_geodetic(200.0, -300.0)
    square = json.loads(_polygon_geojson([tuple(p) for p in SCENARIO1.polygon], SCENARIO1.origin))
    geojson = {
        "type": "FeatureCollection",
        "features": [
            {"type": "Feature", "properties": {}, "geometry": square},
            {
                "type": "Feature",
                "properties": {"nofly": "yes", "radius": 75},
                "geometry": {"type": "Point", "coordinates": [lon, lat]},
            },
            {
                "type": "Feature",
                "properties": {},
                "geometry": {"type": "LineString", "coordinates": [[0, 0], [1, 1]]},
            },
        ],
    }
    ring = " ".join(f"{x},{y}" for x, y in square["coordinates"][0])
    kml = f"""<kml xmlns="http://www.opengis.net/kml/2.2"><Document>
<Placemark><Polygon><outerBoundaryIs><LinearRing><coordinates>{ring}</coordinates></LinearRing>
</outerBoundaryIs></Polygon></Placemark>
<Placemark><name>NOFLY mast</name><ExtendedData><Data name="radius"><value>75</value></Data></ExtendedData>
<Point><coordinates>{lon},{lat},0</coordinates></Point></Placemark>
</Document></kml>"""
    mixed = kml.replace("<Point>", "<MultiGeometry><Point>").replace(
        "</Point>", "</Point><LineString><coordinates>1,2 3,4</coordinates></LineString></MultiGeometry>"
    )
    for data in (json.dumps(geojson).encode(), kml.encode(), mixed.encode()):
        local = local_area(parse_area(data, "f"), SCENARIO1.origin)
        zone = local.nofly[0]
        assert isinstance(zone, LocalCircle) and math.dist((zone.x, zone.y), (200.0, -300.0)) < CM
        assert zone.radius == 75.0
    assert "not a polygon" in parse_area(json.dumps(geojson).encode(), "f").notes[0]


def test_a_no_fly_point_needs_a_radius() -> None:
    doc = {
        "type": "Feature",
        "properties": {"nofly": True},
        "geometry": {"type": "Point", "coordinates": [149, -35]},
    }
    with pytest.raises(MissionError, match="radius"):
        parse_area(json.dumps(doc).encode(), "f")


@settings(max_examples=25, deadline=None)
@given(
    lat=st.floats(-80, 80),
    lon=st.floats(-170, 170),
    n=st.integers(3, 12),
    radius=st.floats(50, 8000),
    jitter=st.lists(st.floats(0.3, 1.0), min_size=12, max_size=12),
)
def test_local_to_file_to_local_round_trips_within_a_centimetre(
    lat: float, lon: float, n: int, radius: float, jitter: list[float]
) -> None:
    origin = Origin(lat=lat, lon=lon, alt=0.0)
    points = [(x * jitter[i], y * jitter[i]) for i, (x, y) in enumerate(_star(n, radius))]
    frame = LocalFrame(origin)
    plan = {
        "fileType": "Plan",
        "geoFence": {
            "polygons": [{"inclusion": True, "polygon": [frame.to_geodetic(*p)[:2] for p in points]}]
        },
    }
    for data in (_polygon_geojson(points, origin), json.dumps(plan).encode()):
        local: LocalArea = local_area(parse_area(data, "f"), origin)
        assert len(local.inclusion) == n
        assert all(min(math.dist(p, q) for q in local.inclusion) < CM for p in points)


def test_the_command_on_a_real_file() -> None:
    path = SHIPPED / "scenario1_nofly.plan"
    origin = f"--origin={SCENARIO1.origin.lat},{SCENARIO1.origin.lon},{SCENARIO1.origin.alt}"
    done = subprocess.run(
        [sys.executable, "-m", "companion.cli", "area", str(path), origin],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=ROOT,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    assert "(-1000.00, -1000.00), (1000.00, -1000.00), (1000.00, 1000.00), (-1000.00, 1000.00)" in done.stdout
    assert "no-fly zone 0: 4 vertices: (-450.00, 200.00), (450.00, 260.00)" in done.stdout
    assert "area: 4,000,000 m^2 (4.000 km^2)" in done.stdout
    assert "searchable (the area less its no-fly zones): 3,865,000 m^2 (3.865 km^2)" in done.stdout
    assert "origin: latitude -35.3632610, longitude 149.1652300, altitude 584 m (given)" in done.stdout
    bad = subprocess.run(
        [sys.executable, "-m", "companion.cli", "area", str(HERE / "swapped.geojson")],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=ROOT,
        check=False,
    )
    assert bad.returncode == 2 and bad.stdout == ""
    assert bad.stderr.count("\n") == 1 and bad.stderr.startswith(
        f"error: area file {HERE / 'swapped.geojson'}"
    )
