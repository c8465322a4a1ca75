"""`uavsearch export`: a run's tracks, sectors and detections as GeoJSON, KML and a QGroundControl plan."""

from __future__ import annotations

import csv
import json
import math
import shutil
from pathlib import Path

import fastkml
import numpy as np
import pytest
import shapely
from fastkml.utils import find_all
from shapely.geometry import shape

from companion.app import operator_files
from companion.app.operator_files import export
from companion.app.operator_run import load_picture
from companion.batch.experiments import compare
from companion.batch.report import copy_mission
from companion.cli import export as export_command
from companion.contracts.areas import local_area, read_area
from companion.contracts.frames import LocalFrame
from companion.core.feasibility import load_mission
from tests.cli import ROOT, uavsearch

SCENARIO1 = ROOT / "mission_files" / "scenario1.toml"
STEPS = 30
CM = 0.01  # the files' 1e-7 degree is about a centimetre


@pytest.fixture(scope="module")
def mc_out(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A two-algorithm batch study of scenario 1, its trajectories saved, and its files exported."""
    out = tmp_path_factory.mktemp("mc")
    compare(
        load_mission(SCENARIO1),
        ["proposed", "no-ta"],
        1,
        STEPS,
        1,
        out,
        workers=1,
        save_trajectories=True,
        progress=False,
    )
    copy_mission(SCENARIO1, out)
    export(load_picture(out, "proposed", 0), out)
    return out


def _features(out: Path, layer: str) -> list[dict]:
    doc = json.loads((out / "operator.geojson").read_text())
    return [f for f in doc["features"] if f["properties"]["layer"] == layer]


def test_geojson_is_valid_lon_lat_and_tracks_start_at_the_starts(mc_out: Path) -> None:
    mission = load_mission(SCENARIO1)
    doc = json.loads((mc_out / "operator.geojson").read_text())
    assert doc["type"] == "FeatureCollection" and doc["uavsearch"]["algorithm"] == "proposed"
    for feature in doc["features"]:
        geometry = shape(feature["geometry"])
        assert geometry.is_valid and not geometry.is_empty, feature["properties"]["name"]
        lon, lat = geometry.representative_point().coords[0]
        assert 149.15 < lon < 149.18 and -35.38 < lat < -35.35, "RFC 7946 orders lon, lat"
    frame = LocalFrame(mission.region.origin)
    tracks = _features(mc_out, "track")
    assert [t["properties"]["uav"] for t in tracks] == list(range(mission.n_uavs))
    for track, vehicle in zip(tracks, mission.vehicles, strict=True):
        lat, lon, _ = frame.to_geodetic(vehicle.x, vehicle.y)
        first = track["geometry"]["coordinates"][0]
        assert first == pytest.approx([lon, lat], abs=1e-7)
        assert len(track["geometry"]["coordinates"]) == STEPS
        assert track["properties"]["altitude_m"] == mission.altitude_of(track["properties"]["uav"])


def test_sectors_partition_the_cells_and_detections_are_the_targets_found(mc_out: Path) -> None:
    picture = load_picture(mc_out, "proposed", 0)
    sectors = _features(mc_out, "sector")
    assert sum(s["properties"]["cells"] for s in sectors) == 2500, "every cell in exactly one sector"
    held = [s["properties"]["uav"] for s in sectors]
    assert held[:-1] == list(range(4)) and held[-1] is None
    shapes = [s.shape for s in picture.sectors]
    assert shapely.union_all(shapes).area == pytest.approx(picture.region.area)
    assert sum(s.area for s in shapes) == pytest.approx(picture.region.area), "sectors do not overlap"
    with (mc_out / "targets.csv").open() as f:
        rows = [r for r in csv.DictReader(f) if (r["algorithm"], r["run"]) == ("proposed", "0")]
    found = {int(r["cell"]): int(r["found_step"]) for r in rows}
    detections = _features(mc_out, "detection")
    assert {d["properties"]["cell"]: d["properties"]["step"] for d in detections} == {
        c: s for c, s in found.items() if s >= 0
    }
    assert all(d["properties"]["true"] is None and d["properties"]["uav"] in range(4) for d in detections)


def test_kml_parses_with_the_same_coordinates(mc_out: Path) -> None:
    document = fastkml.KML.from_string((mc_out / "operator.kml").read_bytes())
    placemarks = [
        p for p in find_all(document, of_type=fastkml.Placemark) if isinstance(p, fastkml.Placemark)
    ]
    doc = json.loads((mc_out / "operator.geojson").read_text())
    assert [p.name for p in placemarks] == [f["properties"]["name"] for f in doc["features"]]
    for placemark, feature in zip(placemarks, doc["features"], strict=True):
        assert placemark.geometry is not None
        ours = shape(placemark.geometry.__geo_interface__)
        assert ours.equals_exact(shape(feature["geometry"]), 1e-9), placemark.name
        data = {d.name: d.value for d in placemark.extended_data.elements}
        assert data["layer"] == feature["properties"]["layer"]
    folders = [f.name for f in find_all(document, of_type=fastkml.Folder)]
    assert folders == ["Search region", "Sectors", "Tracks", "Detections"]


def test_every_file_reads_back_as_the_missions_region(mc_out: Path) -> None:
    mission = load_mission(SCENARIO1)
    for name in ("sectors.plan", "operator.geojson", "operator.kml"):
        area = local_area(read_area(mc_out / name), mission.region.origin)
        assert np.asarray(area.inclusion) == pytest.approx(np.asarray(mission.region.polygon), abs=CM), name
        assert not area.nofly


def test_the_plan_holds_each_sector_as_an_inclusion_polygon(mc_out: Path) -> None:
    plan = json.loads((mc_out / "sectors.plan").read_text())
    assert (plan["fileType"], plan["version"], plan["groundStation"]) == ("Plan", 1, "QGroundControl")
    assert plan["mission"]["items"] == [] and plan["rallyPoints"]["points"] == []
    fence = plan["geoFence"]
    assert fence["version"] == 2 and fence["circles"] == []
    picture = load_picture(mc_out, "proposed", 0)
    parts = [p for s in picture.sectors for p in s.shape.geoms]
    assert len(fence["polygons"]) == 1 + len(parts)
    assert all(p["inclusion"] is True and len(p["polygon"]) >= 3 for p in fence["polygons"])
    lat, lon = fence["polygons"][1]["polygon"][0]
    assert -35.38 < lat < -35.35 and 149.15 < lon < 149.18, "a plan orders lat, lon"


def test_an_algorithm_without_tasks_shows_the_cvt_held_by_no_uav(mc_out: Path) -> None:
    picture = load_picture(mc_out, "no-ta", 0)
    assert [s.uav for s in picture.sectors] == [None] and picture.sectors[0].cells == 2500
    assert picture.notes and "no tasks" in picture.notes[0]


def test_a_flown_runs_detections_are_checked_against_the_truth(mc_out: Path, tmp_path: Path) -> None:
    run = tmp_path / "flown"
    shutil.copytree(mc_out, run)
    found = [d for d in load_picture(mc_out, "proposed", 0).detections]
    truth = [{"cell": d.cell} for d in found]
    (run / "truth.json").write_text(json.dumps({"targets": truth}))
    false_cell = next(c for c in range(2500) if c not in {d.cell for d in found})
    (run / "uav2.json").write_text(json.dumps({"found_cells": [found[0].cell, false_cell]}))
    detections = load_picture(run, "proposed", 0).detections
    assert [(d.cell, d.true) for d in detections] == [*((d.cell, True) for d in found), (false_cell, False)]
    assert detections[-1].step is None and detections[-1].uav is None


def test_the_command_writes_the_formats_asked_for(mc_out: Path, tmp_path: Path) -> None:
    assert export_command.FORMATS == operator_files.FORMATS
    proc = uavsearch("export", str(mc_out), "--format", "plan,kml", "--out", str(tmp_path), "--run", "0")
    assert proc.returncode == 0, proc.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["operator.kml", "sectors.plan"]
    assert (tmp_path / "sectors.plan").read_bytes() == (mc_out / "sectors.plan").read_bytes()
    missing = uavsearch("export", str(tmp_path))
    assert missing.returncode == 2 and "summary.json: missing" in missing.stderr
    proc = uavsearch("export", str(mc_out), "--algorithm", "no-ta", "--out", str(tmp_path / "b"))
    assert proc.returncode == 0 and "note: no-ta divides no tasks" in proc.stdout


def test_the_no_fly_zones_read_back_from_every_file(tmp_path: Path) -> None:
    """A mission with the example's band and a typed circle: each file marks both as no-fly zones
    (GeoJSON `"nofly": true`, KML Placemarks named "no-fly ...", the plan's exclusions), so the
    area reader gives the mission's zones back, to the centimetre."""
    nofly = ROOT / "mission_files" / "scenario1_nofly.toml"
    text = nofly.read_text().replace(
        "[prior]", '[[region.nofly]]\ntype = "circle"\nx = -500.0\ny = 600.0\nradius = 120.0\n\n[prior]', 1
    )
    shutil.copytree(ROOT / "mission_files" / "areas", tmp_path / "areas")
    mission_file = tmp_path / "mission.toml"
    mission_file.write_text(text)
    mission = load_mission(mission_file)
    out = tmp_path / "mc"
    compare(mission, ["proposed"], 1, STEPS, 1, out, workers=1, save_trajectories=True, progress=False)
    copy_mission(mission_file, out)
    export(load_picture(out, "proposed", 0), out)
    band, circle = mission.region.nofly
    for name in ("sectors.plan", "operator.geojson", "operator.kml"):
        area = local_area(read_area(out / name), mission.region.origin)
        kinds = sorted(type(z).__name__ for z in area.nofly)
        assert len(area.nofly) == 2, (name, area.nofly)
        polygon = next(z for z in area.nofly if hasattr(z, "ring"))
        assert len(polygon.ring) == len(band.ring), name
        assert all(math.dist(p, q) < CM for p, q in zip(polygon.ring, band.ring, strict=True)), name
        if name == "sectors.plan":  # a plan keeps a circle a circle
            assert kinds == ["LocalCircle", "LocalPolygon"]
            c = next(z for z in area.nofly if hasattr(z, "radius"))
            assert math.dist((c.x, c.y), (circle.x, circle.y)) < CM and c.radius == circle.radius
