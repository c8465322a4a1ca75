"""Missions whose region comes from an operator's file (`[region] area = "FILE"`) with no-fly zones.

The example mission reads the same region, zones and origin whether its area is the .plan, the
GeoJSON or the KML; every bad input is one `MissionError` line naming the file; a run's copy of
the mission (out/mission.toml) reads as the original does.
"""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import pytest

from companion.batch.report import copy_mission
from companion.contracts.frames import LocalFrame
from companion.contracts.mission import Mission, MissionError, NoFlyPolygon, Region
from companion.core.feasibility import load_mission

ROOT = Path(__file__).resolve().parents[2]
NOFLY = ROOT / "mission_files" / "scenario1_nofly.toml"
AREAS = ROOT / "mission_files" / "areas"
PLAN_LINE = 'area = "areas/scenario1_nofly.plan"'
ORIGIN_LINE = "origin = { lat = -35.363261, lon = 149.165230, alt = 584.0 }"
CM = 0.01


def _mission(tmp_path: Path, area: str, text: str | None = None, name: str = "") -> Path:
    """The example mission as `tmp_path`/`name`.toml naming `area` (relative), beside the area files."""
    (tmp_path / "areas").mkdir(exist_ok=True)
    for path in AREAS.glob("scenario1_nofly.*"):
        shutil.copy(path, tmp_path / "areas" / path.name)
    text = (text if text is not None else NOFLY.read_text()).replace(PLAN_LINE, f'area = "{area}"')
    mission = tmp_path / f"{name or Path(area).suffix[1:]}.toml"
    mission.write_text(text)
    return mission


def _same_region(a: Region, b: Region) -> None:
    """The same polygon, zones and origin, to the centimetre."""
    assert len(a.polygon) == len(b.polygon) and len(a.nofly) == len(b.nofly) > 0
    for p, q in zip(a.polygon, b.polygon, strict=True):
        assert math.dist(p, q) < CM
    for z, w in zip(a.nofly, b.nofly, strict=True):
        assert isinstance(z, NoFlyPolygon) and isinstance(w, NoFlyPolygon)
        assert all(math.dist(p, q) < CM for p, q in zip(z.ring, w.ring, strict=True))
    assert math.hypot(*LocalFrame(a.origin).to_local(b.origin.lat, b.origin.lon)) < CM
    assert abs(a.origin.alt - b.origin.alt) < CM


@pytest.mark.parametrize("origin", ["given", "centroid"])
def test_the_area_as_plan_geojson_or_kml_gives_one_mission(tmp_path: Path, origin: str) -> None:
    text = NOFLY.read_text()
    if origin == "centroid":
        assert ORIGIN_LINE in text
        text = text.replace(ORIGIN_LINE, "")
    missions = [load_mission(_mission(tmp_path, f"areas/scenario1_nofly.{ext}", text)) for ext in
                ("plan", "geojson", "kml")]  # fmt: skip
    if origin == "given":
        missions.append(load_mission(NOFLY))
        assert missions[0].region.origin.alt == 584.0
    else:  # the area's centroid, at altitude 0: the square's centre, near the given origin
        o = missions[0].region.origin
        assert o.alt == 0.0 and math.hypot(*LocalFrame(o).to_local(-35.363261, 149.165230)) < 1.0
    for m in missions[1:]:
        _same_region(missions[0].region, m.region)
    band = missions[0].region.nofly[0]
    assert isinstance(band, NoFlyPolygon) and len(band.ring) == 4
    corners = {(round(x), round(y)) for x, y in missions[0].region.polygon}
    assert corners == {(-1000, -1000), (1000, -1000), (1000, 1000), (-1000, 1000)}


def test_a_run_s_copy_of_the_mission_reads_its_area(tmp_path: Path) -> None:
    out = tmp_path / "out"
    out.mkdir()
    copy_mission(NOFLY, out)
    assert (out / "areas" / "scenario1_nofly.plan").read_bytes() == (
        AREAS / "scenario1_nofly.plan"
    ).read_bytes()
    _same_region(load_mission(out / "mission.toml").region, load_mission(NOFLY).region)


def _error(path: Path) -> MissionError:
    with pytest.raises(MissionError) as caught:
        load_mission(path)
    assert "\n" not in str(caught.value) and "Traceback" not in str(caught.value)
    return caught.value


def _covering_starts(mission: Mission, path: Path) -> None:
    """A GeoJSON of the example's area whose no-fly band covers the start line (y = -980 m)."""
    frame = LocalFrame(mission.region.origin)

    def ring(points: list[tuple[float, float]]) -> list[list[float]]:
        lonlat = [list(frame.to_geodetic(x, y)[1::-1]) for x, y in points]
        return [*lonlat, lonlat[0]]

    def feature(points: list[tuple[float, float]], nofly: bool) -> dict:
        geometry = {"type": "Polygon", "coordinates": [ring(points)]}
        return {"type": "Feature", "properties": {"nofly": nofly}, "geometry": geometry}

    area = [(-1000.0, -1000.0), (1000.0, -1000.0), (1000.0, 1000.0), (-1000.0, 1000.0)]
    band = [(-900.0, -995.0), (900.0, -995.0), (900.0, -900.0), (-900.0, -900.0)]
    doc = {"type": "FeatureCollection", "features": [feature(area, False), feature(band, True)]}
    path.write_text(json.dumps(doc))


def test_each_bad_input_is_one_line_naming_the_file(tmp_path: Path) -> None:
    text = NOFLY.read_text()
    both = _mission(tmp_path, "areas/scenario1_nofly.plan", text.replace(
        PLAN_LINE, f'{PLAN_LINE}\npolygon = [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]]'), "both")  # fmt: skip
    err = _error(both)
    assert (err.source, err.field) == (str(both), "region.area") and "not both" in err.reason

    missing = _mission(tmp_path, "areas/nowhere.plan")
    err = _error(missing)
    assert (err.source, err.field) == (str(missing), "region.area")
    assert err.reason.startswith(f"{tmp_path / 'areas' / 'nowhere.plan'}: (file): No such file")

    covering = _mission(tmp_path, "areas/covers_starts.geojson")
    _covering_starts(load_mission(NOFLY), tmp_path / "areas" / "covers_starts.geojson")
    err = _error(covering)
    assert (err.source, err.field) == (str(covering), "vehicles[0]")
    assert "inside region.nofly[0]" in err.reason

    crossing = (
        '[[region.nofly]]\ntype = "polygon"\nring = [[0.0, 0.0], [100.0, 100.0], [100.0, 0.0], [0.0, 100.0]]'
    )
    typed = _mission(
        tmp_path, "areas/scenario1_nofly.kml", text.replace("[prior]", f"{crossing}\n[prior]", 1), "typed"
    )
    err = _error(typed)
    assert (err.source, err.field) == (str(typed), "region.nofly[1].ring")  # after the area's own zone
    assert "crosses itself near (50.00, 50.00)" in err.reason
