"""The Monte Carlo study: the paper's main claim on scenario 3, and the CLI's files."""

from __future__ import annotations

import csv
import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from companion.batch.montecarlo import SUMMARY_KEYS, run_specs, specs_for, summarize
from companion.core.feasibility import load_mission
from tests.cli import uavsearch

ROOT = Path(__file__).resolve().parents[2]


def test_the_study_on_scenario3_stays_connected_and_separated() -> None:
    """Figure 11 (c), (d): lambda_2 > 0 and every pair beyond R_s throughout every run, between
    sampling moments too, for all three algorithms."""
    mission = load_mission(ROOT / "mission_files/scenario3.toml")
    runs, algorithms = 16, ("proposed", "no-ta", "pheromone")
    results = list(run_specs(specs_for(mission, algorithms, runs, 300, 7, lambda r: False), workers=2))
    summary = {a: summarize(results[i * runs : (i + 1) * runs]) for i, a in enumerate(algorithms)}
    for s in summary.values():
        assert s.min_lambda2 > 0
        assert s.min_distance > mission.comms.safety
    assert all(r.separation_losses == 0 and r.link_losses == 0 for r in results)
    assert min(r.approach.min() for r in results) > mission.comms.safety + mission.safety.buffer


def test_mc_cli_writes_summary_runs_curves_trajectories_and_plots(tmp_path: Path) -> None:
    out = tmp_path / "mc"
    proc = uavsearch(
        "mc",
        "--mission",
        "mission_files/scenario1.toml",
        "--runs",
        "2",
        "--steps",
        "25",
        "--seed",
        "3",
        "--out",
        str(out),
        "--workers",
        "2",
        "--save-trajectories",
    )
    assert proc.returncode == 0, proc.stderr
    assert "scenario1: 6 runs on 2 local processes: 6/6 runs" in proc.stderr  # progress off a terminal
    summary = json.loads((out / "summary.json").read_text())
    for name in ("proposed", "no-ta", "pheromone"):
        assert set(summary[name]) >= SUMMARY_KEYS
        assert summary[name]["runs"] == 2
        assert 0 <= summary[name]["mean_target_time"] <= 25
    with (out / "trajectories.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert {"run", "step", "uav", "x", "y", "heading"} <= set(rows[0])
    assert len(rows) == 3 * 2 * 25 * 4
    with (out / "runs.csv").open() as f:
        runs = list(csv.DictReader(f))
    assert len(runs) == 6
    for name in ("proposed", "no-ta", "pheromone"):
        mine = [r for r in runs if r["algorithm"] == name]
        mean = np.mean([float(r["mean_uncertainty"]) for r in mine])
        assert mean == pytest.approx(summary[name]["mean_uncertainty_over_run"], abs=1e-6)
        events = sum(int(r["separation_losses"]) > 0 or int(r["link_losses"]) > 0 for r in mine)
        assert summary[name]["runs_with_event"] == events == 0
        closest = min(float(r["closest_approach"]) for r in mine)
        assert closest == pytest.approx(summary[name]["closest_approach"], abs=1e-3)
        assert 60.0 < closest <= min(float(r["min_distance"]) for r in mine) + 1e-3
        # a perfect sensor: the first look confirms, nothing false; summary.json as before
        for r in mine:
            assert r["mean_confirm_time"] == r["mean_target_time"] and r["false_confirmations"] == "0"
            assert int(r["never_confirmed"]) == int(r["targets"]) - int(r["targets_found"])
        assert "mean_confirm_time" not in summary[name]
    assert "Confirmed detections" not in proc.stdout
    for png in ("prior_cvt.png", "trajectories.png", "uncertainty.png", "targets_found.png", "pos.png"):
        assert (out / png).read_bytes()[:4] == b"\x89PNG"


def test_a_run_is_the_same_whatever_else_is_in_the_batch(tmp_path: Path) -> None:
    a, b = tmp_path / "a", tmp_path / "b"
    for out, runs in ((a, "1"), (b, "3")):
        proc = uavsearch(
            "mc",
            "--mission",
            "mission_files/scenario2.toml",
            "--algorithms",
            "proposed",
            "--runs",
            runs,
            "--steps",
            "20",
            "--seed",
            "5",
            "--out",
            str(out),
            "--quiet",
            "--workers",
            "2",
        )
        assert proc.returncode == 0, proc.stderr
        assert "runs," not in proc.stderr  # --quiet: no progress
    with (a / "runs.csv").open() as f:
        first = next(csv.DictReader(f))
    with (b / "runs.csv").open() as f:
        same = next(r for r in csv.DictReader(f) if r["run"] == "0")
    for key in ("mean_target_time", "final_uncertainty", "min_lambda2", "min_distance"):
        assert first[key] == same[key]
    traj = np.loadtxt(a / "trajectories.csv", delimiter=",", skiprows=1, usecols=(4, 5))
    assert traj.shape == (20 * 4, 2)
    # targets.csv holds every run, recorded or not, and agrees with runs.csv run by run
    with (b / "targets.csv").open() as f:
        targets = list(csv.DictReader(f))
    with (b / "runs.csv").open() as f:
        for row in csv.DictReader(f):
            mine = [int(t["found_step"]) for t in targets if t["run"] == row["run"]]
            assert len(mine) == int(row["targets"]) > 0
            assert sum(s >= 0 for s in mine) == int(row["targets_found"])
            times = [s if s >= 0 else 20 for s in mine]
            assert np.mean(times) == pytest.approx(float(row["mean_target_time"]), abs=1e-3)


def test_sweep_cli_writes_points_and_plot(tmp_path: Path) -> None:
    proc = uavsearch(
        "sweep",
        "--mission",
        "mission_files/scenario2.toml",
        "--param",
        "n_g",
        "--values",
        "10,30",
        "--runs",
        "2",
        "--steps",
        "20",
        "--out",
        str(tmp_path),
        "--quiet",
    )
    assert proc.returncode == 0, proc.stderr
    points = json.loads((tmp_path / "sweep.json").read_text())["points"]
    assert [p["n_g"] for p in points] == [10, 30]
    assert (tmp_path / "sweep_n_g.png").exists()


def test_bench_cli_prints_figures(tmp_path: Path) -> None:
    proc = uavsearch(
        "bench",
        "--missions",
        "mission_files/scenario1.toml",
        "--runs",
        "1",
        "--steps",
        "20",
        "--workers",
        "1",
        "--json",
        str(tmp_path / "bench.json"),
    )
    assert proc.returncode == 0, proc.stderr
    assert "s / 1,000 steps" in proc.stdout
    result = json.loads((tmp_path / "bench.json").read_text())
    assert {r["algorithm"] for r in result["per_algorithm"]} == {"proposed", "no-ta", "pheromone"}
    t = result["throughput"]
    assert t["runs"] == 8 * 3 and 0 < t["startup_seconds"] <= t["wall_seconds"]
    assert result["study_estimate_minutes"] > 0
    assert result["study_definition"].startswith("1 mission x 3 algorithms x 1,000 runs")
    assert {(r["pd"], r["pd_edge"], r["pf"]) for r in result["per_algorithm"]} == {(1.0, 1.0, 0.0)}
    assert "perfect" in proc.stdout


def test_bench_sensor_flies_every_mission_with_that_detector(tmp_path: Path) -> None:
    """`bench --sensor PD,PF` without --against: the rows and the JSON name the sensor flown."""
    proc = uavsearch(
        "bench",
        "--missions",
        "mission_files/scenario1.toml",
        "mission_files/scenario3.toml",
        "--sensor",
        "0.7,0.05",
        "--runs",
        "1",
        "--steps",
        "10",
        "--study-runs",
        "1",
        "--workers",
        "1",
        "--json",
        str(tmp_path / "bench.json"),
    )
    assert proc.returncode == 0, proc.stderr
    rows = json.loads((tmp_path / "bench.json").read_text())["per_algorithm"]
    assert {r["mission"] for r in rows} == {"scenario1", "scenario3"}
    assert {(r["pd"], r["pd_edge"], r["pf"]) for r in rows} == {(0.7, 0.7, 0.05)}
    assert proc.stdout.count("Pd 0.7, Pf 0.05") == 6


def test_bad_mission_file_is_a_clear_error_without_traceback(tmp_path: Path) -> None:
    bad = tmp_path / "bad.toml"
    text = (
        (ROOT / "mission_files/scenario1.toml").read_text().replace("cell_size = 40.0", 'cell_size = "big"')
    )
    bad.write_text(text)
    proc = uavsearch("mc", "--mission", str(bad), "--runs", "1", "--steps", "5", "--out", str(tmp_path))
    assert proc.returncode == 2
    assert str(bad) in proc.stderr and "region.cell_size" in proc.stderr
    assert "Traceback" not in proc.stderr


def _children(pid: int) -> set[int]:
    out = set()
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            out.add(int(stat.parent.name))
    return out


def test_sigterm_stops_a_study_and_its_workers(tmp_path: Path) -> None:
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "companion.cli",
            "mc",
            "--mission",
            "mission_files/scenario1.toml",
            "--runs",
            "40",
            "--steps",
            "1000",
            "--workers",
            "2",
            "--out",
            str(tmp_path),
            "--quiet",
        ],
        cwd=ROOT,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        deadline = time.monotonic() + 120
        workers: set[int] = set()
        while len(workers) < 2 and time.monotonic() < deadline:  # the pool is up
            workers = {
                p for p in _children(proc.pid) if "spawn_main" in Path(f"/proc/{p}/cmdline").read_text()
            }
            time.sleep(0.2)
        assert len(workers) == 2
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=120) == 130
        for pid in workers:
            assert (
                not Path(f"/proc/{pid}").exists()
                or "spawn_main" not in Path(f"/proc/{pid}/cmdline").read_text()
            )
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
