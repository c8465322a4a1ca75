"""The fault matrix's rogue rows: a secured swarm (`uavsearch run`, lockstep) under attack.

Real processes on loopback: the simulator, four companions, and two rogues (tests/trust/rogue.py):
an outsider without credentials, and an insider holding UAV 1's mesh credentials and signing key
(a compromised member) that puts bundles as UAV 0 and commands the vehicles over unsigned or
wrongly signed MAVLink. Both fail to inject, and the counters say so:

- the outsider never gets a link (its own count of peers stays 0) and hears nothing;
- every companion counts exactly the insider's spoofed, forged and unauthenticated bundles, and
  none of those it put on UAV 0's key (access control drops them before any companion sees them);
- the simulator counts exactly the insider's unsigned and badly signed MAVLink commands;
- the mission flies exactly as the batch engine flies it (lockstep reproduces it): the same
  manoeuvres, the same targets found at the same steps, the same separation.
"""

from __future__ import annotations

import csv
import json
import re
from pathlib import Path

import numpy as np
import pytest

from companion.batch.engine import simulate
from companion.node import keys
from tests.e2e.conftest import PY, STARTUP_S, Procs
from tests.trust.conftest import secure_file

pytestmark = pytest.mark.timeout(600)
STEPS, SEED, N = 80, 3, 3
INSIDER, VICTIM = 1, 0


def _json_line(text: str) -> dict:
    return json.loads([line for line in text.splitlines() if line.startswith("{")][-1])


def _trajectory(out: Path, n: int) -> np.ndarray:
    traj = np.full((STEPS, n, 3), np.nan)
    with (out / "trajectories.csv").open() as f:
        for row in csv.DictReader(f):
            if (k := int(row["step"])) < STEPS:
                traj[k, int(row["uav"])] = (float(row["x"]), float(row["y"]), float(row["heading"]))
    return traj


def test_rogue_peers_fail_to_inject_into_a_secured_swarm(make_mission, procs: Procs, tmp_path: Path) -> None:
    keys.generate(tmp_path / "keys", 4)
    keys.generate(tmp_path / "foreign", 4)
    mission = secure_file(make_mission(n=4, kinematics="grid"), tmp_path / "keys")
    m = mission.mission
    out = tmp_path / "out"
    rogue = [PY, "-m", "tests.trust.rogue"]
    attack = [str(mission.path), str(INSIDER), str(VICTIM), str(N)]
    insider = procs.start("insider", [*rogue, "insider", *attack])
    outsider = procs.start("outsider", [*rogue, "outsider", str(mission.path), str(tmp_path / "foreign")])
    run = procs.start(
        "run",
        [PY, "-m", "companion.app.cli", "run", str(mission.path), "--lockstep", "--steps", str(STEPS),
         "--seed", str(SEED), "--keep-going", "--quiet", "--out", str(out)],
    )  # fmt: skip
    assert insider.wait(STARTUP_S + 240) == 0, insider.text()
    assert run.wait(STARTUP_S + 300) in (0, 1), run.text()  # 1: the short mission's criteria
    assert outsider.stop() == 0
    assert "secured: mesh over mutually authenticated TLS" in run.text()

    did = _json_line(insider.text())
    assert did["alive"] == [0, 1, 2, 3] and did["peers"] >= 4, "the insider's credentials do join"
    seen = _json_line(outsider.text())
    assert seen["puts"] > 0 and seen["peers_max"] == 0 and seen["received"] == 0, seen

    for i in range(m.n_uavs):
        report = json.loads((out / f"uav{i}.json").read_text())
        mesh = report["mesh"]
        assert report["steps"] == STEPS
        rejected = (mesh["spoofed"], mesh["forged"], mesh["unauthenticated"], mesh["malformed"])
        assert rejected == (N, N, 2 * N, 0), (i, mesh)
        assert report["mavlink_signed"] and report["mavlink_unauthenticated"] == 0
    stats = json.loads(re.findall(r"sim_vehicles stats: (.*)", (out / "sim.log").read_text())[-1])["input"]
    assert (stats["unsigned"], stats["bad_signature"]) == (m.n_uavs * N, m.n_uavs * N), stats

    batch = simulate(m, SEED, 0, STEPS, record=True)
    assert batch.trajectory is not None
    flown = _trajectory(out, m.n_uavs)
    assert not np.isnan(flown).any(), "every UAV logged every step"
    assert np.abs(flown[:, :, :2] - batch.trajectory[:, :, :2]).max() <= 0.1
    assert np.abs(np.angle(np.exp(1j * (flown[:, :, 2] - batch.trajectory[:, :, 2])))).max() < 1e-6
    truth = json.loads((out / "truth.json").read_text())
    assert sorted(t["cell"] for t in truth["targets"]) == batch.target_cells.tolist()
    summary = json.loads((out / "summary.json").read_text())["proposed"]
    assert summary["mean_target_time"] == pytest.approx(float(batch.target_times().mean()))
    assert summary["min_distance"] == pytest.approx(float(batch.min_distance.min()), abs=0.1)
