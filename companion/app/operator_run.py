"""A finished run as the operator sees it: each UAV's track, its sector and the detections, in metres.

`load_picture` reads the output directory of `uavsearch run` or of `uavsearch mc
--save-trajectories` (trajectories.csv, targets.csv, summary.json, mission.toml; a flown run's
truth.json and uav{i}.json) and rebuilds the CVT tasks with `build_world`, as the run built them.
`companion.app.operator_files` writes the result as GeoJSON, KML and a QGroundControl plan; the
sectors and the detections are defined in docs/companion.md, "Files for the operator".
"""

from __future__ import annotations

import csv
import json
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import msgspec
import numpy as np
import shapely
from shapely.geometry import MultiPolygon, Polygon

from companion.contracts.mission import Mission, assign_layers
from companion.core.feasibility import load_mission
from companion.core.world import World, build_world

NEEDED = ("summary.json", "mission.toml", "trajectories.csv", "targets.csv")


class ExportError(ValueError):
    """A directory that cannot be exported: names the file and the reason."""


@dataclass(frozen=True)
class Track:
    """One UAV's poses (x east, y north; m) at steps 0, 1, ..., on its layer `altitude` m up."""

    uav: int
    altitude: float
    points: np.ndarray  # (steps, 2)


@dataclass(frozen=True)
class Sector:
    """The CVT tasks credited to `uav` (None: held by no UAV), as one shape in metres."""

    uav: int | None
    tasks: tuple[int, ...]
    cells: int
    shape: MultiPolygon


@dataclass(frozen=True)
class Detection:
    """A target cell reported found: where, when (step, s), by which UAV, and whether it is a target."""

    cell: int
    x: float
    y: float
    step: int | None
    uav: int | None
    true: bool | None  # None: a batch run, whose camera is the ground truth itself


@dataclass(frozen=True)
class Picture:
    """One run of an output directory: its mission and what the operator's files show of it."""

    mission: Mission
    algorithm: str
    run: int
    seed: int
    flown: bool
    region: Polygon
    tracks: list[Track]
    sectors: list[Sector]
    detections: list[Detection]
    notes: list[str]


def _rows(path: Path) -> Iterator[dict[str, str]]:
    """The rows of a CSV file, or the ExportError naming it."""
    try:
        with path.open(newline="") as f:
            yield from csv.DictReader(f)
    except OSError as exc:
        raise ExportError(f"{path}: unreadable ({exc.strerror or exc})") from None


def _json(path: Path) -> dict:
    """A JSON object file, or the ExportError naming it."""
    try:
        doc = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise ExportError(f"{path}: unreadable ({exc})") from None
    if not isinstance(doc, dict):
        raise ExportError(f"{path}: not a JSON object")
    return doc


def load_picture(directory: Path, algorithm: str | None = None, run: int | None = None) -> Picture:
    """Run `run` of `algorithm` (default: the first in trajectories.csv) of an output directory."""
    for name in NEEDED:
        if not (directory / name).is_file():
            raise ExportError(
                f"{directory / name}: missing; export needs the output of `uavsearch run` or "
                "`uavsearch mc --save-trajectories`"
            )
    mission = load_mission(directory / "mission.toml")
    meta = _json(directory / "summary.json").get("_meta")
    if not isinstance(meta, dict) or not isinstance(meta.get("seed"), int):
        raise ExportError(f"{directory / 'summary.json'}: no _meta.seed")
    seed, flown = int(meta["seed"]), (directory / "truth.json").is_file()
    poses, tasks, algorithm, run = _trajectory(directory, mission.n_uavs, algorithm, run)
    mission = _with_starts(directory, mission, run)
    world = build_world(mission.with_algorithm(algorithm), seed, run)
    notes: list[str] = []
    layers = assign_layers(
        [(v.x, v.y) for v in mission.vehicles], [v.layer for v in mission.vehicles], mission.layer_count
    )
    tracks = [
        Track(i, mission.layer_altitude(layers[i]), poses[:, i, :2].copy()) for i in range(mission.n_uavs)
    ]
    if world.tessellation is None:
        notes.append(
            f"{algorithm} divides no tasks: the sectors are the proposed method's CVT regions, held by no UAV"
        )
        world = build_world(mission.with_algorithm("proposed"), seed, run)
    sectors = _sectors(world, tasks)
    detections = _detections(directory, world, poses, algorithm, run, flown)
    region = Polygon(mission.region.polygon)
    return Picture(mission, algorithm, run, seed, flown, region, tracks, sectors, detections, notes)


def _trajectory(
    directory: Path, n: int, algorithm: str | None, run: int | None
) -> tuple[np.ndarray, np.ndarray, str, int]:
    """Poses (steps, n, 3) and tasks (steps, n) of the chosen run of trajectories.csv, and its key."""
    path = directory / "trajectories.csv"
    rows: list[dict[str, str]] = []
    chosen: tuple[str, int] | None = None
    try:
        for row in _rows(path):
            key = (row["algorithm"], int(row["run"]))
            if chosen is None and algorithm in (None, key[0]) and run in (None, key[1]):
                chosen = key
            if key == chosen:
                rows.append(row)
        if chosen is None:
            wanted = f"{algorithm or 'any algorithm'} run {'any' if run is None else run}"
            raise ExportError(f"{path}: no rows for {wanted}")
        steps = 1 + max(int(r["step"]) for r in rows)
        poses = np.zeros((steps, n, 3))
        tasks = np.full((steps, n), -1, dtype=np.int64)
        for r in rows:
            k, i = int(r["step"]), int(r["uav"])
            poses[k, i] = (float(r["x"]), float(r["y"]), float(r["heading"]))
            tasks[k, i] = int(r["task"])
    except (KeyError, ValueError, IndexError) as exc:
        raise ExportError(f"{path}: a malformed row ({exc!r})") from None
    return poses, tasks, *chosen


def _with_starts(directory: Path, mission: Mission, run: int) -> Mission:
    """The mission with run `run`'s starts from starts.csv (`uavsearch mc --random-starts`), if any."""
    path = directory / "starts.csv"
    if not path.is_file():
        return mission
    vehicles = list(mission.vehicles)
    try:
        for row in _rows(path):
            if int(row["run"]) == run:
                i = int(row["uav"])
                vehicles[i] = msgspec.structs.replace(
                    vehicles[i], x=float(row["x"]), y=float(row["y"]), heading_deg=float(row["heading_deg"])
                )
    except (KeyError, ValueError, IndexError) as exc:
        raise ExportError(f"{path}: a malformed row ({exc!r})") from None
    return msgspec.structs.replace(mission, vehicles=tuple(vehicles))


def _polygons(shape: shapely.Geometry) -> MultiPolygon:
    """The polygons of a shape, without collinear or repeated vertices, as one MultiPolygon."""
    parts = [p for p in shapely.get_parts(shape) if isinstance(p, Polygon) and not p.is_empty]
    return MultiPolygon([p.simplify(0.0) for p in parts])


def _sectors(world: World, tasks: np.ndarray) -> list[Sector]:
    """Each UAV's sector: the CVT tasks it held longest (ties: the lower id); the rest held by none.

    A task's shape is the union of its cells' squares, clipped to the region."""
    tess, grid = world.tessellation, world.grid
    assert tess is not None
    half = grid.cell_size / 2
    x, y = grid.centres[:, 0], grid.centres[:, 1]
    cells = shapely.box(x - half, y - half, x + half, y + half)
    n = tasks.shape[1]
    holder: dict[int | None, list[int]] = {}
    for j in range(tess.n_tasks):
        steps = (tasks == j).sum(axis=0)
        uav = int(np.argmax(steps)) if steps.max() > 0 else None
        holder.setdefault(uav, []).append(j)
    region = Polygon(world.mission.region.polygon)
    sectors = []
    for uav in [*range(n), None]:
        mine = holder.get(uav, [])
        if not mine:
            continue
        inside = np.isin(tess.labels, mine)
        shape = shapely.union_all(cells[inside]).intersection(region)
        sectors.append(Sector(uav, tuple(mine), int(inside.sum()), _polygons(shape)))
    return sectors


def _detections(
    directory: Path, world: World, poses: np.ndarray, algorithm: str, run: int, flown: bool
) -> list[Detection]:
    """The targets found (targets.csv), each by the UAV nearest it then; a flown run's false reports.

    A flown run's detections are marked true or false against truth.json; a cell the companions
    reported found (uav{i}.json) that holds no target is a false detection of no known step."""
    centres, found = world.grid.centres, []
    path = directory / "targets.csv"
    try:
        for row in _rows(path):
            step = int(row["found_step"])
            if (row["algorithm"], int(row["run"])) != (algorithm, run) or step < 0:
                continue
            cell = int(row["cell"])
            x, y = centres[cell]
            uav = int(np.argmin(np.hypot(poses[step, :, 0] - x, poses[step, :, 1] - y)))
            found.append(Detection(cell, float(x), float(y), step, uav, True if flown else None))
    except (KeyError, ValueError, IndexError) as exc:
        raise ExportError(f"{path}: a malformed row ({exc!r})") from None
    if not flown:
        return found
    truth = {int(t["cell"]) for t in _json(directory / "truth.json").get("targets", [])}
    reported: set[int] = set()
    for i in range(world.mission.n_uavs):
        report = directory / f"uav{i}.json"
        if report.is_file():
            reported.update(int(c) for c in _json(report).get("found_cells", []))
    for cell in sorted(reported - truth):
        if 0 <= cell < len(centres):
            x, y = centres[cell]
            found.append(Detection(cell, float(x), float(y), None, None, False))
    return found
