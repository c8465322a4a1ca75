"""`uavsearch run`: the whole swarm with one command.

Starts the simulator, a Zenoh router when the mission's mesh is in client mode, and one companion
per UAV, each as a subprocess; shows live progress; ends when every target is found or after K
steps; stops every child; scores the run against the simulator's truth record and writes the
batch engine's files (summary.json, trajectories.csv, plots) plus one MAVLink .tlog per vehicle.
Exits 1 when the mission's pass criteria fail.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from companion.app.evaluation import CompanionLogs, evaluate, failed_criteria, truth_cells
from companion.batch import plots, report
from companion.batch.engine import warm_up
from companion.core.connectivity import algebraic_connectivity, min_pair_distance
from companion.core.world import World, build_world
from companion.mission import load_mission

START_TIMEOUT_S = 120.0
STOP_TIMEOUT_S = 15.0


@dataclass(frozen=True)
class RunOptions:
    mission_file: Path
    out: Path
    speedup: float = 10.0
    lockstep: bool = False
    steps: int | None = None
    seed: int | None = None
    command_mode: str = "turn-rate"
    flavour: str | None = None
    progress: bool = True
    keep_going: bool = False  # fly all the steps even when every target is found
    view: bool = False  # serve the live map (`uavsearch view`) while the swarm flies
    view_port: int = 0


class Children:
    """The subprocesses this launcher started, stopped by PID and never left behind."""

    def __init__(self) -> None:
        self.procs: dict[str, subprocess.Popen] = {}

    def start(self, name: str, argv: list[str], log: Path) -> subprocess.Popen:
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        with log.open("w") as f:
            proc = subprocess.Popen(argv, stdout=f, stderr=subprocess.STDOUT, env=env, start_new_session=True)
        self.procs[name] = proc
        return proc

    def stop(self) -> None:
        for proc in self.procs.values():
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
        deadline = time.monotonic() + STOP_TIMEOUT_S
        for proc in self.procs.values():
            try:
                proc.wait(max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


def _wait_for_line(log: Path, text: str, proc: subprocess.Popen, timeout: float) -> str:
    """The first line of `log` holding `text`, once it is there; raises if `proc` exits first."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if log.exists():
            for line in log.read_text(errors="replace").splitlines():
                if text in line:
                    return line
        if proc.poll() is not None:
            raise RuntimeError(
                f"{log.name}: exited with {proc.returncode}:\n{log.read_text(errors='replace')}"
            )
        time.sleep(0.1)
    raise RuntimeError(f"{log.name}: '{text}' not seen within {timeout:.0f} s")


def _live_line(
    world: World,
    logs: CompanionLogs,
    new: dict[int, list[dict[str, float]]],
    xy: np.ndarray,
    seen: np.ndarray,
) -> str:
    """The progress line; marks in `seen` the targets (centres `xy`) in view of the rows in `new`."""
    m = world.mission
    for rows in new.values():
        if rows:
            p = np.array([(r["x"], r["y"]) for r in rows])
            near = np.sum((p[:, None, :] - xy[None, :, :]) ** 2, axis=-1) <= world.grid.fov_radius2
            seen |= near.any(axis=0)
    latest = [rows[max(rows)] for rows in logs.logs.values() if rows]
    if not latest:
        return "waiting for the companions"
    step = int(min(r["step"] for r in latest))
    pos = np.array([(r["x"], r["y"]) for r in latest])
    unc = float(np.mean([r["mean_eta"] for r in latest]))
    lam = algebraic_connectivity(pos, m.comms.range)
    mind = min_pair_distance(pos)
    return (
        f"step {step:5d}  targets {int(seen.sum())}/{len(xy)}  mean uncertainty {unc:.4f}  "
        f"lambda_2 {lam:.4f}  min distance {mind:7.1f} m"
    )


def run_mission(opts: RunOptions) -> int:
    """Fly the mission end to end; returns the process exit code."""
    mission = load_mission(opts.mission_file)
    seed = mission.seed if opts.seed is None else opts.seed
    steps = opts.steps or mission.steps
    out = opts.out
    out.mkdir(parents=True, exist_ok=True)
    for stale in out.glob("uav*.*"):
        stale.unlink()
    world = build_world(mission, seed, 0)
    logs = CompanionLogs(out, mission.n_uavs)
    if opts.progress:
        print("loading the algorithm's compiled kernels (compiling them on a first run)", flush=True)
    warm_up(mission)  # once here, so that the companions load the kernels from numba's cache
    py = sys.executable
    children = Children()
    stop = threading.Event()
    previous = {s: signal.signal(s, lambda *_: stop.set()) for s in (signal.SIGINT, signal.SIGTERM)}
    started = time.monotonic()
    try:
        if mission.mesh.mode == "client":
            router = children.start(
                "router",
                [py, "-m", "companion.app.cli", "router", "--mission", str(opts.mission_file)],
                out / "router.log",
            )
            _wait_for_line(out / "router.log", "router listening", router, START_TIMEOUT_S)
        if opts.view:
            argv = [py, "-m", "companion.app.cli", "view", "--mission", str(opts.mission_file)]
            argv += ["--seed", str(seed), "--port", str(opts.view_port)]
            view = children.start("view", argv, out / "view.log")
            line = _wait_for_line(out / "view.log", "view at ", view, START_TIMEOUT_S)
            print(f"live map of the swarm: {line.split('view at ', 1)[1]}", flush=True)
        for i in range(mission.n_uavs):
            argv = [
                py,
                "-m",
                "companion.app.cli",
                "companion",
                "--mission",
                str(opts.mission_file),
                "--uav",
                str(i),
                "--takeover",
                "--steps",
                str(steps),
                "--seed",
                str(seed),
                "--out",
                str(out),
                "--command-mode",
                opts.command_mode,
            ]
            if opts.lockstep:
                argv.append("--lockstep")
            children.start(f"companion{i}", argv, out / f"companion{i}.log")
        for i in range(mission.n_uavs):  # companions first: each waits for its vehicle's heartbeat
            proc = children.procs[f"companion{i}"]
            _wait_for_line(out / f"companion{i}.log", "waiting for the vehicle", proc, START_TIMEOUT_S)
        sim_argv = [
            py,
            "-m",
            "sim_vehicles",
            "--mission",
            str(opts.mission_file),
            "--seed",
            str(seed),
            "--truth",
            str(out / "truth.json"),
            "--speedup",
            str(opts.speedup),
        ]
        if opts.lockstep:
            sim_argv.append("--lockstep")
        if opts.flavour:
            sim_argv += ["--flavour", opts.flavour]
        sim = children.start("sim", sim_argv, out / "sim.log")
        _wait_for_line(out / "sim.log", f"vehicle {mission.n_uavs - 1} ", sim, START_TIMEOUT_S)
        targets = truth_cells(out / "truth.json")
        seen = np.zeros(len(targets), dtype=bool)
        last_print = 0.0
        while not stop.is_set():
            time.sleep(0.5)
            line = _live_line(world, logs, logs.poll(), world.grid.centres[targets], seen)
            if opts.progress and time.monotonic() - last_print >= 2.0:
                print(line, flush=True)
                last_print = time.monotonic()
            companions = [p for n, p in children.procs.items() if n.startswith("companion")]
            all_found = seen.all() and not opts.keep_going
            if all_found or all(p.poll() is not None for p in companions):
                break
            if sim.poll() is not None:
                print("error: the simulator stopped", file=sys.stderr)
                break
    finally:
        children.stop()
        for s, h in previous.items():
            signal.signal(s, h)
    logs.poll()
    result = evaluate(world, logs.logs, targets, time.monotonic() - started, seed)
    if result.steps == 0:
        print(
            "error: no step was flown (see the companion and sim logs in the output directory)",
            file=sys.stderr,
        )
        return 1
    name = mission.algorithm.name
    summary = report.write_summary(
        out,
        {name: [result]},
        {"mission": mission.name, "seed": seed, "distributed": True, "lockstep": opts.lockstep},
    )
    report.write_trajectories(out, {name: [result]})
    report.write_steps(out, {name: [result]})
    report.write_targets(out, {name: [result]})
    report.copy_mission(opts.mission_file, out)
    plots.plot_prior(out / "prior_cvt.png", world)
    plots.plot_trajectories(out / "trajectories.png", {name: world}, {name: result})
    plots.plot_uncertainty(out / "uncertainty.png", {name: [result]})
    plots.plot_found(out / "targets_found.png", {name: [result]})
    plots.plot_links(out / "links.png", result, mission.comms.safety)
    if opts.view:
        print(f"replay the run with: uavsearch view --replay {out}", flush=True)
    failures = failed_criteria(world, result)
    s = summary[name]
    print(
        f"{mission.name}: {result.steps} steps, targets found {int(np.sum(result.target_steps >= 0))}/"
        f"{len(targets)}, mean target time {s['mean_target_time']:.1f}, min lambda_2 {s['min_lambda2']:.4f}, "
        f"min distance {s['min_distance']:.1f} m"
    )
    (out / "criteria.json").write_text(
        json.dumps({"passed": not failures, "failures": failures}, indent=2) + "\n"
    )
    if failures:
        print("pass criteria FAILED: " + "; ".join(failures), file=sys.stderr)
        return 1
    print(f"pass criteria met; wrote {out}")
    return 0
