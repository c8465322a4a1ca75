"""`uavsearch run FILE --vehicles URL,...`: one companion per UAV attached to vehicles that already
exist (here the bundled simulator, started on its own, with its camera), scored against the
mission's ground truth, which the launcher writes itself (the same draw as the simulator's)."""

from __future__ import annotations

import json
from pathlib import Path

from tests.e2e.conftest import PY, STARTUP_S, Procs, assert_follows, read_csv, searched

STEPS = 40


def test_run_attaches_to_existing_vehicles(make_mission, procs: Procs, tmp_path: Path) -> None:
    mission = make_mission(n=2)
    k = mission.mission.kinematics
    procs.sim(mission, "--speedup", "5", "--truth", str(tmp_path / "sim-truth.json"))
    links = ",".join(f"udpout:127.0.0.1:{port}" for port in mission.ports)
    out = tmp_path / "out"
    argv = [PY, "-m", "companion.cli", "run", str(mission.path), "--vehicles", links]
    argv += [
        "--command-mode",
        "turn-rate",
        "--steps",
        str(STEPS),
        "--out",
        str(out),
        "--quiet",
        "--keep-going",
    ]
    run = procs.start("run", argv)
    assert run.wait(timeout=STARTUP_S + 120) in (0, 1), run.text()
    assert json.loads((out / "truth.json").read_text()) == json.loads(
        (tmp_path / "sim-truth.json").read_text()
    )
    assert json.loads((out / "summary.json").read_text())["proposed"]["runs"] == 1
    for i in range(mission.n):
        rows = read_csv(out / f"uav{i}.csv")
        assert len(searched(rows)) == STEPS
        assert_follows(rows, k.speed, k.step, f"uav{i} on an existing vehicle")
    bad = procs.start("bad", [*argv[:6], links.split(",")[0], "--out", str(tmp_path / "bad")])
    assert bad.wait(timeout=STARTUP_S) == 2 and "--vehicles: 1 links for the mission's 2 UAVs" in bad.text()
