"""`uavsearch run` with an imperfect sensor: candidates and confirmations apart, only true ones scored."""

from __future__ import annotations

import csv
import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np

from companion.batch.engine import simulate
from companion.core.feasibility import load_mission

ROOT = Path(__file__).resolve().parents[2]
SCENARIO1 = ROOT / "mission_files/scenario1.toml"
# the batch engine's run of these finds in 110 steps 6 of the 9 targets confirmed and 2 empty
# cells confirmed (false alarms), with about a hundred cells raised as candidates on the way
SENSOR = "pd = 0.9\npf = 0.05\nconfirm = 0.9\n"
SEED, STEPS = 2, 110


def _mission(tmp_path: Path, base_port: int) -> Path:
    """scenario1 with a detector that misses and raises false alarms, on its own ports and key space."""
    text = SCENARIO1.read_text().replace('name = "scenario1"', 'name = "scenario1_sensing"')
    text = text.replace("[sensor]\n", f"[sensor]\n{SENSOR}", 1)
    text = text.replace("min_targets_found = 7", "min_targets_found = 9\nmax_false_confirmations = 0")
    text += f'\n[sim]\nbase_port = {base_port}\n\n[mesh]\nkey_prefix = "testsensing"\n'
    text += f'seed_endpoint = "tcp/127.0.0.1:{base_port + 7}"\nrouter = "tcp/127.0.0.1:{base_port + 8}"\n'
    path = tmp_path / "mission.toml"
    path.write_text(text)
    return path


def _confirmed(out: Path, n: int) -> dict[int, int]:
    """The first scored confirmation step of each cell, read straight from the companions' logs."""
    first: dict[int, int] = {}
    for i in range(n):
        with (out / f"uav{i}.csv").open() as f:
            closing = {int(r["step"]) for r in csv.DictReader(f) if r["closing"] == "1"}
        with (out / f"uav{i}_targets.csv").open() as f:
            for r in csv.DictReader(f):
                step, cell = int(r["step"]), int(r["cell"])
                if r["event"] == "confirmed" and step not in closing:
                    first[cell] = min(first.get(cell, step), step)
    return first


def test_only_confirmed_true_targets_are_scored(tmp_path: Path, free_base_port: int) -> None:
    """Candidates and confirmations are logged apart; the pass criteria count confirmed true targets
    only and name the false confirmations; the lockstep run confirms what the batch engine does."""
    mission = _mission(tmp_path, free_base_port)
    out = tmp_path / "out"
    proc = subprocess.run(
        [sys.executable, "-m", "companion.cli", "run", str(mission), "--out", str(out), "--lockstep",
         "--steps", str(STEPS), "--seed", str(SEED), "--keep-going", "--quiet"],
        capture_output=True, text=True, cwd=ROOT, timeout=900,
    )  # fmt: skip
    assert (out / "criteria.json").exists(), proc.stdout + proc.stderr
    m = load_mission(mission)
    logs = "".join((out / f"companion{i}.log").read_text() for i in range(m.n_uavs))
    assert re.search(r"step \d+: candidate target, cell \d+ at .* posterior 0\.\d+", logs)
    assert re.search(r"step \d+: confirmed target, cell \d+ at .* posterior 0\.\d+", logs)

    truth = {int(t["cell"]) for t in json.loads((out / "truth.json").read_text())["targets"]}
    first = _confirmed(out, m.n_uavs)
    true, false = sorted(set(first) & truth), sorted(set(first) - truth)
    assert true, "some target confirmed"
    summary = json.loads((out / "targets_confirmed.json").read_text())
    assert summary["confirmed_true"] == len(true) and summary["false_confirmations"] == len(false)
    assert summary["never_confirmed"] == sorted(truth - set(true))
    assert {c["cell"] for c in summary["confirmed"] if c["scored"] and not c["true"]} == set(false)
    assert len(summary["candidate_cells"]) > len(first), "candidates outnumber the confirmations"
    assert f"targets found {len(true)}/{len(truth)}" in proc.stdout
    failures = json.loads((out / "criteria.json").read_text())["failures"]
    assert f"targets found {len(true)} < 9" in failures  # the false confirmations never count
    assert (f"false confirmations {len(false)} > 0" in failures) == bool(false)
    assert proc.returncode == 1

    reports = [json.loads((out / f"uav{i}.json").read_text()) for i in range(m.n_uavs)]
    assert sum(r["confirmations"] for r in reports) >= len(first)
    assert all(set(r["found_cells"]).isdisjoint(r["candidate_cells"]) for r in reports)

    batch = simulate(m, SEED, 0, STEPS)  # what the Monte Carlo study measures is what flies
    assert batch.sensing is not None
    assert summary["confirmed_true"] == int(np.count_nonzero(batch.sensing.confirm_steps >= 0))
    assert false == batch.sensing.false_cells.tolist()
