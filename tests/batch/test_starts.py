"""Start layouts drawn per run (`uavsearch mc --random-starts`): every layout validates, is separated
and connected, is a pure function of (mission, seed, run), and run r of every algorithm flies it."""

from __future__ import annotations

import csv
import itertools
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from companion.batch.generate import Family, generate
from companion.batch.montecarlo import specs_for
from companion.batch.starts import LAYOUTS, parse_layouts, random_start
from companion.contracts.mission import Mission
from companion.core.feasibility import load_mission, validate
from companion.core.geometry import ConvexPolygon
from companion.core.world import build_grid

ROOT = Path(__file__).resolve().parents[2]
SCENARIOS = [load_mission(ROOT / f"mission_files/scenario{s}.toml") for s in (1, 2, 3)]
GENERATED = 6  # missions of seed 41 of the generator's default family


@pytest.fixture(scope="module")
def generated() -> list[Mission]:
    return [m for m, _ in generate(GENERATED, 41, Family())]


def connected(points: np.ndarray, link: float) -> bool:
    """Breadth-first search over the graph of pairs within `link`."""
    seen, frontier = {0}, [0]
    while frontier:
        i = frontier.pop()
        for j in range(len(points)):
            if j not in seen and math.dist(points[i], points[j]) <= link:
                seen.add(j)
                frontier.append(j)
    return len(seen) == len(points)


def assert_good_start(base: Mission, drawn: Mission) -> None:
    assert drawn.n_uavs == base.n_uavs
    assert validate(drawn) == drawn
    points = np.array([(v.x, v.y) for v in drawn.vehicles])
    separation = base.comms.safety + base.safety.buffer
    for p, q in itertools.combinations(points, 2):
        assert math.dist(p, q) > separation
    assert connected(points, base.comms.range - base.safety.buffer)
    region = ConvexPolygon.from_vertices(np.array(base.region.polygon))
    assert all(region.contains(x, y) for x, y in points)
    if base.kinematics.mode == "grid":  # on cell centres, heading a multiple of 45 degrees
        grid = build_grid(base)
        cells = grid.cell_at(points)
        assert (cells >= 0).all()
        np.testing.assert_allclose(grid.centres[cells], points, atol=0.051)
        assert all(v.heading_deg % 45 == 0 for v in drawn.vehicles)


@pytest.mark.parametrize("index", range(len(SCENARIOS) + GENERATED))
def test_every_drawn_start_layout_validates_and_is_separated_and_connected(
    index: int, generated: list[Mission]
) -> None:
    mission = (SCENARIOS + generated)[index]
    kinds = set()
    for run in range(25):
        drawn, kind = random_start(mission, 7, run)
        assert_good_start(mission, drawn)
        kinds.add(kind)
    assert kinds == set(LAYOUTS)


def test_one_layout_kind_only() -> None:
    for run in range(10):
        drawn, kind = random_start(SCENARIOS[0], 3, run, ("edge",))
        assert kind == "edge"
        ys = {v.y for v in drawn.vehicles}
        xs = {v.x for v in drawn.vehicles}
        assert len(ys) == 1 or len(xs) == 1  # one row along a side of the square


def test_the_start_layout_is_a_pure_function_of_mission_seed_and_run() -> None:
    m = SCENARIOS[1]
    poses = {(s, r): random_start(m, s, r)[0].vehicles for s in (1, 2) for r in range(6)}
    assert all(random_start(m, s, r)[0].vehicles == v for (s, r), v in poses.items())
    # runs and seeds draw anew (an edge layout on a grid square has few distinct variants, so a few
    # runs may repeat one)
    assert len({tuple((v.x, v.y) for v in vs) for vs in poses.values()}) >= 9
    assert [poses[1, r] for r in range(6)] != [poses[2, r] for r in range(6)]
    # ports and everything but the vehicles' poses are the mission's
    drawn = random_start(m, 1, 0)[0]
    assert [drawn.vehicle_port(i) for i in range(m.n_uavs)] == [m.vehicle_port(i) for i in range(m.n_uavs)]
    assert drawn.region == m.region and drawn.algorithm == m.algorithm and drawn.prior == m.prior


def test_specs_pair_run_r_of_every_algorithm_on_one_layout() -> None:
    m = SCENARIOS[0]
    starts = [random_start(m, 5, r)[0] for r in range(4)]
    specs = specs_for(m, ("proposed", "no-ta", "pheromone"), 4, 10, 5, lambda r: False, starts)
    for spec in specs:
        assert spec.mission.vehicles == starts[spec.run].vehicles
        assert spec.seed == 5
    assert {s.mission.algorithm.name for s in specs} == {"proposed", "no-ta", "pheromone"}
    with pytest.raises(ValueError, match="3 start layouts for 4 runs"):
        specs_for(m, ("proposed",), 4, 10, 5, lambda r: False, starts[:3])


def test_unknown_layout_is_an_error() -> None:
    assert parse_layouts("clustered, edge") == ("clustered", "edge")
    with pytest.raises(ValueError, match="unknown start layout 'ring'"):
        parse_layouts("edge,ring")
    with pytest.raises(ValueError, match="unknown start layout ''"):
        parse_layouts(",")


def _mc(out: Path, *extra: str) -> subprocess.CompletedProcess[str]:
    args = ["--mission", "mission_files/scenario3.toml", "--runs", "3", "--steps", "12", "--seed", "9"]
    return subprocess.run(
        [sys.executable, "-m", "companion.cli", "mc", *args, "--out", str(out), "--quiet", *extra],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=600,
    )


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open() as f:
        return list(csv.DictReader(f))


def test_mc_random_starts_flies_each_runs_layout_with_every_algorithm(tmp_path: Path) -> None:
    proc = _mc(tmp_path, "--random-starts", "--save-trajectories", "--workers", "2")
    assert proc.returncode == 0, proc.stderr
    starts = _rows(tmp_path / "starts.csv")
    mission = load_mission(ROOT / "mission_files/scenario3.toml")
    for run in range(3):
        drawn, kind = random_start(mission, 9, run)
        mine = [r for r in starts if r["run"] == str(run)]
        assert {r["layout"] for r in mine} == {kind}
        assert [(float(r["x"]), float(r["y"])) for r in mine] == [(v.x, v.y) for v in drawn.vehicles]
    first = {
        (r["algorithm"], r["run"], r["uav"]): (float(r["x"]), float(r["y"]))
        for r in _rows(tmp_path / "trajectories.csv")
        if r["step"] == "0"
    }
    assert len(first) == 3 * 3 * mission.n_uavs
    for (_, run, uav), xy in first.items():
        s = next(r for r in starts if r["run"] == run and r["uav"] == uav)
        assert xy == (float(s["x"]), float(s["y"]))
    bad = _mc(tmp_path / "bad", "--random-starts", "edge,ring")
    assert bad.returncode == 2
    assert "unknown start layout 'ring'" in bad.stderr and "Traceback" not in bad.stderr
