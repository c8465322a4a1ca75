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
The run flies until the attacks are over (however slowly the machine lets the rogues start) and a
few steps more, then is stopped with Ctrl-C; what it flew is compared.
"""

from __future__ import annotations

import csv
import json
import re
from pathlib import Path

import numpy as np
import pytest

from companion.batch.engine import simulate
from companion.contracts import keys
from tests.e2e.conftest import PY, STARTUP_S, Procs, read_csv, wait_rows
from tests.trust.conftest import secure_file

pytestmark = pytest.mark.timeout(600)
MAX_STEPS, SEED, N = 2000, 3, 3
AFTER = 5  # steps flown after the attacks, before the run is stopped
INSIDER, VICTIM = 1, 0


def _json_line(text: str) -> dict:
    return json.loads([line for line in text.splitlines() if line.startswith("{")][-1])


def _trajectory(out: Path, n: int, steps: int) -> np.ndarray:
    traj = np.full((steps, n, 3), np.nan)
    with (out / "trajectories.csv").open() as f:
        for row in csv.DictReader(f):
            if (k := int(row["step"])) < steps:
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
    swarm_run = {keys.RUN_ENV: "rogue-test"}  # the insider, a member, knows the run (it is no secret)
    run = procs.start(
        "run",
        [PY, "-m", "companion.cli", "run", str(mission.path), "--lockstep", "--steps", str(MAX_STEPS),
         "--seed", str(SEED), "--keep-going", "--quiet", "--out", str(out)],
        env=swarm_run,
    )  # fmt: skip
    # the rogues after the run, whose simulator binds the mission's ports first: a rogue's ephemeral
    # sockets, bound before it, once took one of them ("Address already in use")
    insider = procs.start("insider", [*rogue, "insider", *attack], env=swarm_run)
    outsider = procs.start("outsider", [*rogue, "outsider", str(mission.path), str(tmp_path / "foreign")])
    assert insider.wait(STARTUP_S + 300) == 0, insider.text()
    attacked = max((r["step"] for r in read_csv(out / f"uav{VICTIM}.csv")), default=0)
    for i in range(m.n_uavs):
        wait_rows(out / f"uav{i}.csv", 1, run, STARTUP_S, cond=lambda r: r["step"] >= attacked + AFTER)
    assert run.stop() in (0, 1), run.text()  # Ctrl-C: the run ends with its report; 1: its criteria
    assert outsider.stop() == 0
    assert "secured: mesh over mutually authenticated TLS" in run.text()
    assert "secured run: the companions refused" in run.text(), run.text()[-3000:]

    did = _json_line(insider.text())
    assert did["alive"] == [0, 1, 2, 3] and did["peers"] >= 4, "the insider's credentials do join"
    seen = _json_line(outsider.text())
    assert seen["puts"] > 0 and seen["peers_max"] == 0 and seen["received"] == 0, seen

    steps = 1 + int(min(max(r["step"] for r in read_csv(out / f"uav{i}.csv")) for i in range(m.n_uavs)))
    for i in range(m.n_uavs):
        report = json.loads((out / f"uav{i}.json").read_text())
        mesh = report["mesh"]
        assert report["steps"] >= steps > attacked + AFTER
        rejected = (mesh["spoofed"], mesh["forged"], mesh["unauthenticated"], mesh["malformed"])
        assert rejected == (N, N, 2 * N, 0), (i, mesh)
        refused = {kind: sum(senders.values()) for kind, senders in report["refused"]["mesh"].items()}
        assert refused == {"spoofed bundle": N, "forged bundle": N, "unauthenticated bundle": 2 * N}, refused
        assert report["mavlink_signed"] and report["mavlink_unauthenticated"] == 0
    stats = json.loads(re.findall(r"sim_vehicles stats: (.*)", (out / "sim.log").read_text())[-1])["input"]
    assert (stats["unsigned"], stats["bad_signature"]) == (m.n_uavs * N, m.n_uavs * N), stats

    batch = simulate(m, SEED, 0, steps, record=True)
    assert batch.trajectory is not None
    flown = _trajectory(out, m.n_uavs, steps)
    assert not np.isnan(flown).any(), "every UAV logged every step"
    assert np.abs(flown[:, :, :2] - batch.trajectory[:steps, :, :2]).max() <= 0.1
    assert np.abs(np.angle(np.exp(1j * (flown[:, :, 2] - batch.trajectory[:steps, :, 2])))).max() < 1e-6
    truth = json.loads((out / "truth.json").read_text())
    assert sorted(t["cell"] for t in truth["targets"]) == batch.target_cells.tolist()
    reports = [json.loads((out / f"uav{i}.json").read_text()) for i in range(m.n_uavs)]
    found = set().union(*(r["found_cells"] for r in reports))
    seen = {int(c) for c, k in zip(batch.target_cells, batch.target_steps, strict=True) if 0 <= k < steps - 1}
    assert seen <= found, "every target the batch engine finds in those steps was detected in flight"
