"""`uavsearch run` stopped by a signal while it starts its children: it stops waiting for them at
once, stops every child by PID and says it was stopped (not "error: no step was flown"). Killed
outright (SIGKILL, which it cannot handle), it still leaves no process behind: each child asks the
kernel for SIGTERM when its launcher dies (`companion.contracts.lifeline`)."""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

from tests.e2e.conftest import PY, STARTUP_S, STOP_S, Procs, _same_process_alive, wait_rows


def test_run_stopped_while_starting_stops_its_children_and_says_so(
    make_mission, procs: Procs, tmp_path: Path
) -> None:
    mission = make_mission(n=2)
    out = tmp_path / "out"
    out.mkdir()
    (out / "truth.json").write_text('{"an earlier run": true}')  # not this run's: never scored
    argv = [PY, "-m", "companion.cli", "run", str(mission.path), "--steps", "40", "--out", str(out)]
    run = procs.start("run", argv)
    deadline = time.monotonic() + STARTUP_S
    # the companions are started (after the kernels are loaded and the handlers set), and the
    # launcher waits for their "waiting for the vehicle", which takes them a Python start-up
    while not (out / "companion0.log").exists():
        assert run.alive() and time.monotonic() < deadline, run.text()
        time.sleep(0.02)
    run.refresh()
    children = dict(run.descendants)
    assert children, "the launcher has started its companions"
    assert run.stop() == 1, run.text()  # SIGINT
    text = run.text()
    assert "stopped by a signal while waiting for" in text, text
    assert "error:" not in text, text
    assert "before any step was flown" not in text, text  # nothing scored: there is no truth yet
    assert not [pid for pid, start in children.items() if _same_process_alive(pid, start)]
    for log in out.glob("*.log"):  # stopped while loading their modules: quietly (SIGTERM)
        assert "Traceback" not in log.read_text(), log.read_text()


def test_run_killed_leaves_no_process_behind(make_mission, procs: Procs, tmp_path: Path) -> None:
    mission = make_mission(n=2)
    out = tmp_path / "out"
    argv = [PY, "-m", "companion.cli", "run", str(mission.path), "--steps", "1000", "--out", str(out)]
    run = procs.start("run", argv)
    for i in range(mission.n):  # flying
        wait_rows(out / f"uav{i}.csv", 1, run)
    run.refresh()
    children = dict(run.descendants)
    assert len(children) >= mission.n + 1, "the companions and the simulator"
    os.kill(run.pid, signal.SIGKILL)
    assert run.wait(timeout=STOP_S) == -signal.SIGKILL
    deadline = time.monotonic() + 2 * STOP_S
    while left := [pid for pid, start in children.items() if _same_process_alive(pid, start)]:
        assert time.monotonic() < deadline, f"left behind by the killed launcher: {left}"
        time.sleep(0.2)
