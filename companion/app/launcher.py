"""`uavsearch run`: the whole swarm with one command.

Starts the vehicles, a Zenoh router when the mission's mesh is in client mode, and one companion
per UAV, each as a subprocess; shows live progress; ends when every target is found or after K
steps; stops every child; scores the run against the mission's ground truth and writes the batch
engine's files (summary.json, trajectories.csv, plots), the plan-versus-flight figures
(tracking.json) and one MAVLink .tlog per vehicle. Exits 1 when the mission's pass criteria fail.

The vehicles are the bundled simulator (default); or ArduPlane SITL or PX4 SITL, one instance per
UAV at its start pose (`--autopilot ardupilot-sitl`, `--autopilot px4-sitl`), with the stand-alone
simulated camera reading their positions; or vehicles that already exist (`--vehicles URL,...`,
optionally with the stand-alone camera on `--camera-links URL,...`).
"""

from __future__ import annotations

import json
import math
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from companion.app import px4_sitl, sitl
from companion.app.evaluation import (
    CompanionLogs,
    evaluate,
    failed_criteria,
    flight_report,
    read_approach,
    read_vertical,
    truth_cells,
)
from companion.app.progress import Progress
from companion.batch import plots, report
from companion.core.warm import warm_up
from companion.core.world import build_world
from companion.mission import Mission, load_mission
from companion.node.airframe import Airframe, refusal
from companion.node.frames import LocalFrame
from companion.node.keys import (
    ROLES,
    RUN_ENV,
    for_mission,
    insecure_warning,
    mavlink_secrets,
    new_run_id,
    uav_identity,
)
from companion.node.lifeline import launcher_env
from sim_vehicles import camera as cam

START_TIMEOUT_S = 120.0
STOP_TIMEOUT_S = 30.0  # a companion flies out its trajectory in force first (horizon + 1 steps)
SITL_FLAVOURS = {"ardupilot-sitl": "ardupilot", "px4-sitl": "px4"}


@dataclass(frozen=True)
class RunOptions:
    mission_file: Path
    out: Path
    speedup: float = 10.0
    lockstep: bool = False
    steps: int | None = None
    seed: int | None = None
    command_mode: str | None = None  # None: turn-rate on the bundled simulator, heading otherwise
    flavour: str | None = None
    progress: bool = True
    keep_going: bool = False  # fly all the steps even when every target is found
    view: bool = False  # serve the live map (`uavsearch view`) while the swarm flies
    view_port: int = 0
    autopilot: str = "bundled"  # or "ardupilot-sitl", "px4-sitl"
    vehicles: tuple[str, ...] = ()  # external vehicles, one pymavlink URL per UAV
    camera_links: tuple[str, ...] = ()  # the stand-alone camera's links to the external vehicles
    sitl_binary: str | None = None
    sitl_defaults: str | None = None
    sitl_instance: int = 0  # PX4: the first instance number tried

    @property
    def external(self) -> bool:
        return self.autopilot != "bundled" or bool(self.vehicles)

    @property
    def mode(self) -> str:
        if self.command_mode:
            return self.command_mode
        if self.autopilot == "px4-sitl":
            return "position-target"
        return "heading" if self.external else "turn-rate"


class Interrupted(RuntimeError):
    """A signal stopped the launcher while it waited for a child to start."""


class Children:
    """The subprocesses this launcher started, stopped by PID and never left behind; `stop` (set by
    SIGINT/SIGTERM) cuts any wait for one of them short."""

    def __init__(self, stop: threading.Event | None = None) -> None:
        self.procs: dict[str, subprocess.Popen] = {}
        self.logs: dict[str, Path] = {}
        self.signals: dict[str, int] = {}
        self.env: dict[str, str] = {}  # added to every child's environment (the run identity)
        self._stop = stop if stop is not None else threading.Event()

    def start(
        self,
        name: str,
        argv: list[str],
        log: Path,
        cwd: Path | None = None,
        extra: dict[str, str] | None = None,
        stop_signal: int = signal.SIGTERM,
    ) -> subprocess.Popen:
        """Start `argv` in its own session, output to `log`, with `extra` added to the environment;
        `stop` sends it `stop_signal`: SIGTERM, which our processes handle as they do SIGINT but
        which, unlike SIGINT, ends one still loading its modules with no traceback. Our own
        processes end with this one (`lifeline`)."""
        env = {**os.environ, "PYTHONUNBUFFERED": "1", **launcher_env(), **self.env, **(extra or {})}
        with log.open("w") as f:
            proc = subprocess.Popen(
                argv, stdout=f, stderr=subprocess.STDOUT, env=env, start_new_session=True, cwd=cwd
            )
        self.procs[name], self.logs[name], self.signals[name] = proc, log, stop_signal
        return proc

    def wait_for_line(self, name: str, text: str, timeout: float = START_TIMEOUT_S) -> str:
        """The first line of child `name`'s log holding `text`, once it is there; RuntimeError if
        the child exits first or `timeout` seconds pass, Interrupted if a signal comes first."""
        log, proc = self.logs[name], self.procs[name]
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
            if self._stop.wait(0.1):
                raise Interrupted(f"stopped by a signal while waiting for '{text}' from {name}")
        raise RuntimeError(f"{log.name}: '{text}' not seen within {timeout:.0f} s")

    def stop(self) -> None:
        """Each child's stop signal (SIGTERM unless started otherwise), the companions first: a
        companion ends its step and writes its report while its vehicle, camera and router still
        answer. Whatever has not exited `STOP_TIMEOUT_S` after its signal is killed."""
        companions = [n for n in self.procs if n.startswith("companion")]
        for group in (companions, [n for n in self.procs if n not in companions]):
            for name in group:
                if self.procs[name].poll() is None:
                    self.procs[name].send_signal(self.signals[name])
            deadline = time.monotonic() + STOP_TIMEOUT_S
            for name in group:
                try:
                    self.procs[name].wait(max(0.1, deadline - time.monotonic()))
                except subprocess.TimeoutExpired:
                    self.procs[name].kill()
                    self.procs[name].wait()


def _check_options(opts: RunOptions, mission: Mission) -> str | None:
    """Why the run cannot start (None: it can)."""
    if opts.vehicles and len(opts.vehicles) != mission.n_uavs:
        return f"--vehicles: {len(opts.vehicles)} links for the mission's {mission.n_uavs} UAVs"
    if opts.camera_links and len(opts.camera_links) != mission.n_uavs:
        return f"--camera-links: {len(opts.camera_links)} links for the mission's {mission.n_uavs} UAVs"
    if opts.autopilot in SITL_FLAVOURS:
        if opts.vehicles:
            return f"--vehicles and --autopilot {opts.autopilot} exclude each other"
        airframe = Airframe(SITL_FLAVOURS[opts.autopilot], {}, simulator=False)
        problem = refusal(mission, airframe, opts.mode)
        if problem:
            return f"--autopilot {opts.autopilot}: {problem}"
        if opts.autopilot == "px4-sitl" and mission.secured and mission.security.mavlink_signing:
            return (
                "--autopilot px4-sitl: the PX4 SITL links are not MAVLink2-signed (PX4 is given no secret): "
                "set [security] mavlink_signing = false for it"
            )
    return None


def _companion_argv(opts: RunOptions, i: int, steps: int, seed: int, url: str | None) -> list[str]:
    argv = [
        sys.executable,
        "-m",
        "companion.app",
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
        str(opts.out),
        "--journal",
        str(opts.out / f"uav{i}.journal"),
        "--command-mode",
        opts.mode,
    ]
    if url is not None:
        argv += ["--vehicle", url]
    if opts.lockstep:
        argv.append("--lockstep")
    return argv


def _start_camera(
    children: Children, opts: RunOptions, links: list[str], seed: int, n: int, setup_signing: bool = False
) -> subprocess.Popen:
    """The stand-alone camera on `links`; returns once it has every vehicle's position stream.
    `setup_signing`: it gives each vehicle its MAVLink signing secret first (SITL's SERIAL0)."""
    out = opts.out
    camera = children.start(
        "camera",
        [
            sys.executable,
            "-m",
            "companion.app",
            "camera",
            "--mission",
            str(opts.mission_file),
            "--vehicles",
            ",".join(links),
            "--seed",
            str(seed),
            "--truth",
            str(out / "truth.json"),
            *(["--setup-signing"] if setup_signing else []),
            "--approach",
            str(out / "approach.csv"),
        ],
        out / "camera.log",
    )
    for i in range(n):
        children.wait_for_line("camera", f"camera: vehicle {i} up")
    return camera


def _start_sitl(children: Children, opts: RunOptions, mission: Mission, seed: int) -> list[str]:
    """One ArduPlane SITL per UAV and the stand-alone camera on their SERIAL0 (which starts their
    clocks together); returns the companions' links (SERIAL1)."""
    binary = sitl.find_binary(opts.sitl_binary)
    defaults = sitl.find_defaults(binary, opts.sitl_defaults)
    for i in range(mission.n_uavs):
        home = opts.out / f"sitl{i}"
        home.mkdir(exist_ok=True)
        argv = sitl.sitl_argv(binary, defaults, mission, i, opts.speedup)
        children.start(f"sitl{i}", argv, opts.out / f"sitl{i}.log", cwd=home, stop_signal=sitl.STOP_SIGNAL)
    ports = [sitl.sitl_ports(mission, i) for i in range(mission.n_uavs)]
    signing = mavlink_secrets(mission) is not None
    _start_camera(children, opts, [p.url(p.serial0) for p in ports], seed, mission.n_uavs, signing)
    return [p.url(p.serial1) for p in ports]


def _start_px4(children: Children, opts: RunOptions, mission: Mission, seed: int) -> list[str]:
    """One PX4 SITL per UAV (its own working directory, made afresh) and the stand-alone camera on
    their camera links; returns the companions' links."""
    build = px4_sitl.find_build(opts.sitl_binary)
    px4 = px4_sitl.link_folder(build, opts.out / "px4_bin")
    instances = px4_sitl.free_instances(mission.n_uavs, opts.sitl_instance)
    for i, instance in enumerate(instances):
        workdir = opts.out / f"px4_{i}"
        shutil.rmtree(workdir, ignore_errors=True)
        workdir.mkdir()
        env = px4_sitl.px4_env(mission, i, opts.speedup)
        argv = px4_sitl.px4_argv(px4, build, instance, workdir)
        children.start(f"px4_{i}", argv, opts.out / f"px4_{i}.log", cwd=workdir, extra=env)
    for i in range(mission.n_uavs):
        children.wait_for_line(f"px4_{i}", px4_sitl.STARTED)
    ports = [px4_sitl.px4_ports(mission, i) for i in range(mission.n_uavs)]
    _start_camera(children, opts, [p.url(p.camera) for p in ports], seed, mission.n_uavs)
    return [p.url(p.companion) for p in ports]


def _start_bundled(children: Children, opts: RunOptions, mission: Mission, seed: int) -> None:
    sim_argv = [
        sys.executable,
        "-m",
        "sim_vehicles",
        "--mission",
        str(opts.mission_file),
        "--seed",
        str(seed),
        "--truth",
        str(opts.out / "truth.json"),
        "--approach",
        str(opts.out / "approach.csv"),
        "--speedup",
        str(opts.speedup),
    ]
    if opts.lockstep:
        sim_argv.append("--lockstep")
    if opts.flavour:
        sim_argv += ["--flavour", opts.flavour]
    children.start("sim", sim_argv, opts.out / "sim.log")
    children.wait_for_line("sim", f"vehicle {mission.n_uavs - 1} ")


def _stopped_early(children: Children) -> str | None:
    """What went wrong if a vehicle, the camera or the router exited, or a companion refused to fly
    (exit code 2); a companion that stops otherwise leaves the others flying."""
    for name, proc in children.procs.items():
        rc = proc.poll()
        if rc is None or (name.startswith("companion") and rc != 2):
            continue
        log = children.logs[name]
        last = [line for line in log.read_text(errors="replace").splitlines() if line.startswith("error:")]
        return f"{name} exited with code {rc}: {last[-1] if last else f'see {log}'}"
    return None


def refused_by_companions(out: Path, n: int) -> dict[str, int]:
    """What the companions refused, summed over them, by kind ("mesh forged bundle", "MAVLink bad
    signature", ...), from their reports (uav{i}.json)."""
    total: dict[str, int] = {}
    for i in range(n):
        try:
            refused = json.loads((out / f"uav{i}.json").read_text()).get("refused", {})
        except (OSError, ValueError):
            continue
        for where, kinds in refused.items():
            for kind, senders in kinds.items():
                key = f"{where} {kind}"
                total[key] = total.get(key, 0) + sum(senders.values())
    return total


def security_summary(mission: Mission) -> str:
    """What authenticates this run, after checking that every identity's keys load; the insecure
    warning when nothing does."""
    if not mission.secured:
        return insecure_warning(mission)
    for identity in [uav_identity(i) for i in range(mission.n_uavs)] + list(ROLES):
        for_mission(mission, identity)
    link = "MAVLink2-signed" if mavlink_secrets(mission) else "UNSIGNED ([security] mavlink_signing = false)"
    return (
        f"secured: mesh over mutually authenticated TLS with access control, every bundle signed; "
        f"vehicle links {link}; keys in {mission.security.keys}"
    )


def run_mission(opts: RunOptions) -> int:
    """Fly the mission end to end; returns the process exit code."""
    # absolute paths: the SITL instances run in working directories of their own
    opts = replace(opts, mission_file=opts.mission_file.resolve(), out=opts.out.resolve())
    mission = load_mission(opts.mission_file)
    problem = _check_options(opts, mission)
    if problem:
        print(f"error: {problem}", file=sys.stderr)
        return 2
    security = security_summary(mission)  # raises KeyDirectoryError (a ValueError) for bad keys
    print(security, flush=True)
    seed = mission.seed if opts.seed is None else opts.seed
    steps = opts.steps or mission.steps
    out = opts.out
    out.mkdir(parents=True, exist_ok=True)
    for stale in [*out.glob("uav*.*"), out / "truth.json", out / "approach.csv"]:  # an earlier run's
        stale.unlink(missing_ok=True)
    world = build_world(mission, seed, 0)
    logs = CompanionLogs(out, mission.n_uavs)
    if opts.progress:
        print("loading the algorithm's compiled kernels (compiling them on a first run)", flush=True)
    warm_up(mission)  # once here, so that the companions load the kernels from numba's cache
    stop = threading.Event()
    children = Children(stop)
    run = os.environ.get(RUN_ENV) or new_run_id()  # every child signs for this run only
    children.env[RUN_ENV] = run
    if mission.secured:
        print(f"run {run}: everything signed in this run is refused in any other", flush=True)
    previous = {s: signal.signal(s, lambda *_: stop.set()) for s in (signal.SIGINT, signal.SIGTERM)}
    started = time.monotonic()
    failure = None
    progress: Progress | None = None
    try:
        if mission.mesh.mode == "client":
            children.start(
                "router",
                [sys.executable, "-m", "companion.app", "router", "--mission", str(opts.mission_file)],
                out / "router.log",
            )
            children.wait_for_line("router", "router listening")
        urls: list[str | None] = [None] * mission.n_uavs
        if opts.autopilot == "ardupilot-sitl":
            urls = list(_start_sitl(children, opts, mission, seed))
        elif opts.autopilot == "px4-sitl":
            urls = list(_start_px4(children, opts, mission, seed))
        elif opts.vehicles:
            urls = list(opts.vehicles)
            if opts.camera_links:
                _start_camera(children, opts, list(opts.camera_links), seed, mission.n_uavs)
            else:  # a real detector publishes; score against the mission's simulated ground truth
                grid, targets = cam.draw_truth(mission, seed)
                frame = LocalFrame(mission.region.origin)
                cam.write_truth(out / "truth.json", cam.truth_record(mission, seed, grid, targets, frame))
        if opts.view:
            argv = [sys.executable, "-m", "companion.app", "view", "--mission", str(opts.mission_file)]
            argv += ["--seed", str(seed), "--port", str(opts.view_port)]
            children.start("view", argv, out / "view.log")
            line = children.wait_for_line("view", "view at ")
            print(f"live map of the swarm: {line.split('view at ', 1)[1]}", flush=True)
        for i in range(mission.n_uavs):
            argv = _companion_argv(opts, i, steps, seed, urls[i])
            if opts.vehicles and mavlink_secrets(mission) is not None:  # not ours to provision: their key
                argv += ["--mavlink-key", str(Path(mission.security.keys) / uav_identity(i) / "mavlink.key")]
            children.start(f"companion{i}", argv, out / f"companion{i}.log")
        if not opts.external:
            for i in range(mission.n_uavs):  # companions first: each waits for its vehicle's heartbeat
                children.wait_for_line(f"companion{i}", "waiting for the vehicle")
            _start_bundled(children, opts, mission, seed)
        targets = truth_cells(out / "truth.json")
        progress = Progress(world, world.grid.centres[targets], started)
        last_print = 0.0
        while not stop.is_set():
            time.sleep(0.5)
            line = progress.update(logs.logs, logs.poll(), time.monotonic())
            if opts.progress and line is not None and time.monotonic() - last_print >= 2.0:
                print(line, flush=True)
                last_print = time.monotonic()
            companions = [p for n, p in children.procs.items() if n.startswith("companion")]
            all_found = progress.seen.all() and not opts.keep_going
            if all_found or all(p.poll() is not None for p in companions):
                break
            failure = _stopped_early(children)
            if failure:
                break
    except (RuntimeError, sitl.SitlError) as exc:
        failure = str(exc)
    finally:
        children.stop()
        for s, h in previous.items():
            signal.signal(s, h)
    if failure:
        print(failure if stop.is_set() else f"error: {failure}", file=sys.stderr)
        if not (out / "truth.json").exists():
            return 1
    new = logs.poll()
    if opts.progress and progress is not None:  # the last line: the steps the summary counts
        line = progress.update(logs.logs, new, time.monotonic(), final=True)
        if line is not None:
            print(line, flush=True)
    approach = read_approach(out / "approach.csv")
    targets = truth_cells(out / "truth.json")
    result = evaluate(world, logs.logs, targets, time.monotonic() - started, seed, approach)
    if result.steps == 0:
        if stop.is_set():
            print("stopped by a signal before any step was flown", file=sys.stderr)
        else:
            print(
                "error: no step was flown (see the companion and vehicle logs in the output directory)",
                file=sys.stderr,
            )
        return 1
    name = mission.algorithm.name
    summary = report.write_summary(
        out,
        {name: [result]},
        {
            "mission": mission.name, "seed": seed, "distributed": True, "lockstep": opts.lockstep,
            "run": run, "refused": refused_by_companions(out, mission.n_uavs),
        },
    )  # fmt: skip
    report.write_trajectories(out, {name: [result]})
    report.write_steps(out, {name: [result]})
    report.write_targets(out, {name: [result]})
    report.copy_mission(opts.mission_file, out)
    plots.plot_prior(out / "prior_cvt.png", world)
    starts = {name: np.array([(v.x, v.y) for v in mission.vehicles])}
    plots.plot_trajectories(out / "trajectories.png", {name: world}, {name: result}, starts)
    plots.plot_uncertainty(out / "uncertainty.png", {name: [result]})
    plots.plot_found(out / "targets_found.png", {name: [result]})
    plots.plot_links(out / "links.png", result, mission.comms.safety)
    flight = flight_report(mission, out, logs.logs)
    vertical = read_vertical(out / "approach.csv")
    flight["steps_within_rs"] = len(vertical)  # a pair horizontally within R_s (approach.csv)
    flight["closest_vertical_within_rs_m"] = min(vertical.values()) if vertical else None
    (out / "tracking.json").write_text(json.dumps(flight, indent=2) + "\n")
    if opts.view:
        print(f"replay the run with: uavsearch view --replay {out}", flush=True)
    closest_flown = min(approach.values()) if approach else math.inf
    failures = failed_criteria(world, result, out / "approach.csv")
    s = summary[name]
    print(
        f"{mission.name}: {result.steps} steps, targets found {int(np.sum(result.target_steps >= 0))}/"
        f"{len(result.target_cells)}, mean target time {s['mean_target_time']:.1f}, "
        f"min lambda_2 {s['min_lambda2']:.4f}, min distance {s['min_distance']:.1f} m"
    )
    if approach:
        source = "stand-alone camera, position streams" if opts.external else "simulator, physics rate"
        print(
            f"closest approach along the flown tracks ({source}): "
            f"{result.approach.min():.1f} m (R_s = {mission.comms.safety:g} m); "
            f"{result.separation_losses} steps within R_s; "
            f"{closest_flown:.1f} m over all it recorded (start-up and hand-over included)"
        )
    if approach:
        within = (
            f"{len(vertical)} steps had a pair within R_s horizontally, at least "
            f"{min(vertical.values()):.1f} m apart vertically"
            if vertical
            else "no pair came within R_s horizontally"
        )
        print(f"in three dimensions: {within}")
    p, h = flight["position_m"], flight["heading_deg"]
    if p["median"] is not None:
        print(
            f"plan vs flight ({opts.mode}): position error median {p['median']:.1f} m, p95 {p['p95']:.1f} m; "
            f"heading error median {h['median']:.1f} deg, p95 {h['p95']:.1f} deg; "
            f"{flight['outside_fence']} logged poses outside the fence"
        )
    refused = summary["_meta"]["refused"]
    if mission.secured and refused:
        kinds = ", ".join(f"{n} {kind}" for kind, n in sorted(refused.items()))
        print(f"secured run: the companions refused {kinds} (who sent them: companion*.log, uav*.json)")
    (out / "criteria.json").write_text(
        json.dumps({"passed": not failures, "failures": failures}, indent=2) + "\n"
    )
    if failures:
        print("pass criteria FAILED: " + "; ".join(failures), file=sys.stderr)
        return 1
    print(f"pass criteria met; wrote {out}")
    if not mission.secured:
        print("this run was INSECURE (no [security] keys): see the warning at its start", flush=True)
    return 0
