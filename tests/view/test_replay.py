"""Replays of `uavsearch mc --save-trajectories` output, and the view command's clear errors."""

from __future__ import annotations

import csv
import json
import shutil
import socket
import subprocess
import sys
import urllib.error
import urllib.request
from pathlib import Path

import pytest

from companion.app.view.replay import ReplayError, load_replay
from companion.batch.experiments import compare
from companion.batch.report import copy_mission
from companion.core.feasibility import load_mission
from tests.e2e.conftest import STARTUP_S, Procs
from tests.view.conftest import ROOT, SCENARIO1

STEPS = 40


@pytest.fixture(scope="module")
def mc_out(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("mc")
    mission = load_mission(SCENARIO1)
    compare(
        mission, ["proposed", "no-ta"], 2, STEPS, 5, out, workers=1, save_trajectories=True, progress=False
    )
    copy_mission(SCENARIO1, out)
    return out


def _csv(path: Path, algorithm: str, run: int) -> list[dict[str, str]]:
    with path.open() as f:
        return [r for r in csv.DictReader(f) if r["algorithm"] == algorithm and int(r["run"]) == run]


def test_any_run_of_a_monte_carlo_study_replays(mc_out: Path) -> None:
    replay = load_replay(mc_out, algorithm="no-ta", run=1)
    assert replay.scene.mode == "replay" and replay.scene.algorithm == "no-ta"
    assert replay.scene.labels is None, "no CVT for the no-ta baseline"
    assert sorted(map(tuple, replay.scene.runs)) == [
        ("no-ta", 0),
        ("no-ta", 1),
        ("proposed", 0),
        ("proposed", 1),
    ]
    frames = [json.loads(f) for f in replay.frames]
    assert [f["k"] for f in frames] == list(range(STEPS))
    steps = _csv(mc_out / "steps.csv", "no-ta", 1)
    poses = _csv(mc_out / "trajectories.csv", "no-ta", 1)
    for f, s in zip(frames, steps, strict=True):
        assert f["m"][0] == int(s["found"]) and f["m"][1] == pytest.approx(float(s["uncertainty"]), abs=1e-7)
    for p in poses:
        u = frames[int(p["step"])]["u"][int(p["uav"])]
        assert u[:2] == pytest.approx([float(p["x"]), float(p["y"])], abs=1e-3) and u[3] == int(p["task"])
    targets = _csv(mc_out / "targets.csv", "no-ta", 1)
    firsts = sorted(int(t["cell"]) for t in targets if int(t["found_step"]) >= 0)
    assert sorted(cell for f in frames for cell, _ in f["f"]) == firsts
    proposed = load_replay(mc_out, algorithm="proposed", run=1).scene
    assert proposed.labels is not None and len(proposed.labels) == len(proposed.prior), "the CVT of that run"


def test_what_cannot_be_replayed_is_named(mc_out: Path, tmp_path: Path) -> None:
    with pytest.raises(ReplayError, match="no rows for proposed run 7"):
        load_replay(mc_out, algorithm="proposed", run=7)
    partial = tmp_path / "partial"
    shutil.copytree(mc_out, partial)
    (partial / "steps.csv").unlink()
    with pytest.raises(ReplayError, match=r"steps.csv: missing"):
        load_replay(partial)
    (partial / "mission.toml").unlink()
    shutil.copy(mc_out / "steps.csv", partial / "steps.csv")
    with pytest.raises(ReplayError, match="give the run's mission with --mission"):
        load_replay(partial)
    assert load_replay(partial, SCENARIO1).frames


def _view(*args: str) -> subprocess.CompletedProcess[str]:
    argv = [sys.executable, "-m", "companion.cli", "view", *args]
    return subprocess.run(argv, capture_output=True, text=True, cwd=ROOT, timeout=STARTUP_S)


def test_the_view_command_names_bad_input(mc_out: Path, tmp_path: Path, procs: Procs) -> None:
    proc = _view("--replay", str(tmp_path / "nowhere"))
    assert proc.returncode == 2 and "summary.json: missing" in proc.stderr and "Traceback" not in proc.stderr
    proc = _view("--replay", str(mc_out), "--algorithm", "pheromone")
    assert proc.returncode == 2 and "no rows for pheromone run any" in proc.stderr
    bad = tmp_path / "bad.toml"
    bad.write_text(SCENARIO1.read_text().replace("cell_size = 40.0", "cell_size = -1.0"))
    proc = _view("--mission", str(bad))
    assert proc.returncode == 2 and "region.cell_size" in proc.stderr
    with socket.socket() as taken:  # a port in use
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        proc = _view("--replay", str(mc_out), "--port", str(taken.getsockname()[1]))
    assert proc.returncode == 1 and "cannot serve on 127.0.0.1" in proc.stderr

    view = procs.start("view", [sys.executable, "-m", "companion.cli", "view", "--replay", str(mc_out),
                                "--port", "0"])  # fmt: skip
    view.wait_for_text("view at ")
    url = view.text().split("view at ", 1)[1].split()[0]
    with urllib.request.urlopen(url + "api/scene?algorithm=no-ta&run=1", timeout=30) as r:
        assert json.load(r)["algorithm"] == "no-ta"
    with pytest.raises(urllib.error.HTTPError) as err:
        urllib.request.urlopen(url + "api/scene?algorithm=no-ta&run=9", timeout=30)
    assert err.value.code == 404
    with urllib.request.urlopen(url + "static/app.js", timeout=30) as r:
        assert b"uavsearch view" in r.read()
    assert view.stop() == 0
