"""Issue 37's metrics and study: POS curves, `uavsearch mc` with an imperfect sensor, `sensing-study`."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from companion.batch.confirmation import pos_curve, run_pos
from companion.batch.engine import simulate
from companion.batch.sensing_study import RunRow, paired_rows
from companion.core.feasibility import load_mission
from tests.cli import uavsearch

ROOT = Path(__file__).resolve().parents[2]


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as f:
        return list(csv.DictReader(f))


def _imperfect(tmp_path: Path, pd: float, pf: float) -> Path:
    """scenario1.toml with `[sensor] pd`, `pf` set."""
    text = (ROOT / "mission_files/scenario1.toml").read_text()
    head, sensor, tail = text.partition("[sensor]\n")
    assert sensor, "scenario1.toml has no [sensor] table"
    path = tmp_path / "scenario1_imperfect.toml"
    path.write_text(f"{head}{sensor}pd = {pd}\npf = {pf}\n{tail}")
    return path


def test_pos_is_the_fraction_of_targets_confirmed_by_each_step() -> None:
    # four targets: confirmed at 2 and 0, one never, one after the horizon (5 steps: 0..4)
    got = pos_curve(np.array([2, -1, 0, 7]), 5)
    assert got.tolist() == [0.25, 0.25, 0.5, 0.5, 0.5]
    assert pos_curve(np.array([4, 1]), 5).tolist() == [0.0, 0.5, 0.5, 0.5, 1.0]
    assert pos_curve(np.array([], dtype=np.int64), 3).tolist() == [1.0, 1.0, 1.0]  # nothing to find


def test_a_perfect_sensors_pos_is_the_targets_found_curve() -> None:
    r = simulate(load_mission(ROOT / "mission_files/scenario1.toml"), 3, 0, 40)
    assert r.sensing is None and (r.target_steps >= 0).any()
    assert np.allclose(run_pos(r) * len(r.target_steps), r.found)


def _row(algorithm: str, run: int, confirm: list[int]) -> RunRow:
    return RunRow("m", 0.9, 0.01, algorithm, run, 1, 10, [0] * len(confirm), confirm, 0)


def test_paired_differences_match_runs_by_index_not_by_position() -> None:
    rows = [
        _row("proposed", 1, [4]),
        _row("proposed", 0, [2]),
        _row("proposed", 2, [-1]),  # never: the run's length, 10
        _row("no-ta", 2, [6]),
        _row("no-ta", 0, [3]),  # no run 1 of no-ta: run 1 is left out
    ]
    (p,) = paired_rows(rows, ["proposed", "no-ta"])
    assert p.baseline == "no-ta" and p.runs == 2
    assert p.difference == pytest.approx(((2 - 3) + (10 - 6)) / 2)
    assert p.proposed == pytest.approx(6.0) and p.baseline_value == pytest.approx(4.5)
    assert p.difference_low < p.difference < p.difference_high


def test_mc_reports_confirmations_of_an_imperfect_sensor(tmp_path: Path) -> None:
    out = tmp_path / "mc"
    mission = _imperfect(tmp_path, 0.8, 0.02)
    proc = uavsearch(
        "mc", str(mission), "--runs", "2", "--steps", "40", "--out", str(out), "--workers", "1", "--quiet"
    )
    assert proc.returncode == 0, proc.stderr
    assert "Confirmed detections" in proc.stdout
    summary = json.loads((out / "summary.json").read_text())
    runs = _rows(out / "runs.csv")
    for name in ("proposed", "no-ta", "pheromone"):
        mine = [r for r in runs if r["algorithm"] == name]
        # a target is confirmed no sooner than first seen
        assert all(float(r["mean_confirm_time"]) >= float(r["mean_target_time"]) - 1e-9 for r in mine)
        mean = np.mean([float(r["mean_confirm_time"]) for r in mine])
        assert summary[name]["mean_confirm_time"] == pytest.approx(mean, abs=1e-3)
        never = np.mean([int(r["never_confirmed"]) for r in mine])
        assert summary[name]["never_confirmed_per_run"] == pytest.approx(never)
        false = np.mean([int(r["false_confirmations"]) for r in mine])
        assert summary[name]["false_confirmations_per_run"] == pytest.approx(false)
    curves = _rows(out / "curves.csv")
    assert all(0.0 <= float(c["pos"]) <= 1.0 for c in curves) and len(curves) == 3 * 40
    assert (out / "pos.png").read_bytes()[:4] == b"\x89PNG"


def _cell_rows(out: Path, pd: str, pf: str) -> list[dict[str, str]]:
    return _rows(out / "cells" / f"scenario1_pd{pd}_pf{pf}.csv")


def _time(rows: list[dict[str, str]], algorithm: str, run: str) -> float:
    """One run's mean time to a confirmed detection from its cell file (never: 60, the steps)."""
    (r,) = (r for r in rows if r["algorithm"] == algorithm and r["run"] == run)
    return float(np.mean([s if s >= 0 else 60 for s in map(int, r["confirm_steps"].split())]))


def test_sensing_study_writes_every_cell_paired_and_resumes(tmp_path: Path) -> None:
    out = tmp_path / "study"
    base = ("sensing-study", "--missions", "mission_files/scenario1.toml", "--pd", "1,0.7", "--pf", "0,0.05")
    tail = ("--steps", "60", "--out", str(out), "--workers", "1")
    args = (*base, "--runs", "2", *tail)
    proc = uavsearch(*args)
    assert proc.returncode == 0, proc.stderr
    assert "sensing study: 4 of 4 cells, 24 runs on 1 local process: 24/24 runs" in proc.stderr
    summary = _rows(out / "summary.csv")
    cells = {(r["pd"], r["pf"], r["algorithm"]) for r in summary}
    algorithms = ("proposed", "no-ta", "pheromone")
    assert cells == {(pd, pf, a) for pd in ("1", "0.7") for pf in ("0", "0.05") for a in algorithms}
    assert len(summary) == 12
    for r in summary:
        if r["pf"] == "0":
            assert float(r["false_confirmations"]) == 0.0
        if (r["pd"], r["pf"]) == ("1", "0"):  # a perfect sensor confirms at first sight
            assert float(r["confirm_time"]) == pytest.approx(float(r["first_sight_time"]))
    for run in _cell_rows(out, "1", "0"):
        assert run["confirm_steps"] == run["target_steps"]
    paired = _rows(out / "paired.csv")
    assert len(paired) == 4 * 2
    for p in paired:
        rows = _cell_rows(out, p["pd"], p["pf"])
        d = [_time(rows, "proposed", run) - _time(rows, p["baseline"], run) for run in ("0", "1")]
        assert float(p["difference"]) == pytest.approx(np.mean(d), rel=1e-5, abs=1e-4)
        assert int(p["runs"]) == 2
    for rows in (_cell_rows(out, pd, pf) for pd in ("1", "0.7") for pf in ("0", "0.05")):
        assert {(r["run"], r["seed"]) for r in rows if r["algorithm"] == "proposed"} == {
            (r["run"], r["seed"]) for r in rows if r["algorithm"] == "pheromone"
        }  # the same runs for every algorithm
    table = (out / "results_table.md").read_text()
    assert table.count("| proposed |") == 4 and "vs no-ta" in table and "vs pheromone" in table
    for png in ("pos_scenario1.png", "confirm_scenario1.png"):
        assert (out / png).read_bytes()[:4] == b"\x89PNG"
    # again in the same folder: every cell read back, nothing flown, the same summary
    before = (out / "summary.csv").read_text()
    again = uavsearch(*args)
    assert again.returncode == 0, again.stderr
    assert "resuming: 4 of 4 cells" in again.stderr and "runs on" not in again.stderr
    assert (out / "summary.csv").read_text() == before
    # another study in that folder is refused
    other = uavsearch(*base, "--runs", "3", *tail)
    assert other.returncode == 2 and "holds another study" in other.stderr
