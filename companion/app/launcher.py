"""`uavsearch run`: the whole swarm with one command (docs/companion.md).

Starts the vehicles (the bundled simulator, ArduPlane or PX4 SITL, or vehicles that exist), a Zenoh
router when the mission's mesh is in client mode, and one companion per UAV, each as a subprocess;
shows live progress; ends when every target is found or after K steps; stops every child; then
scores the run (`companion.app.run_report`). Exits 1 when the mission's pass criteria fail.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from companion.app import px4_sitl, sitl
from companion.app.children import Children
from companion.app.evaluation import CompanionLogs, read_target_logs, truth_cells
from companion.app.progress import Progress
from companion.app.run_options import RunOptions, check_options
from companion.app.run_report import report_run
from companion.contracts.frames import LocalFrame
from companion.contracts.keys import (
    ROLES,
    RUN_ENV,
    for_mission,
    insecure_warning,
    mavlink_secrets,
    new_run_id,
    uav_identity,
)
from companion.contracts.mission import Mission
from companion.core.feasibility import load_mission
from companion.core.warm import warm_up
from companion.core.world import World, build_world
from sim_vehicles import camera as cam


def _companion_argv(opts: RunOptions, i: int, steps: int, seed: int, url: str | None) -> list[str]:
    """The command line of UAV i's companion."""
    argv = [
        sys.executable,
        "-m",
        "companion.cli",
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

    With `setup_signing` it first gives each vehicle its MAVLink signing secret (SITL's SERIAL0).
    """
    out = opts.out
    camera = children.start(
        "camera",
        [
            sys.executable,
            "-m",
            "companion.cli",
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
    """One ArduPlane SITL per UAV and the stand-alone camera; returns the companions' links (SERIAL1).

    Each instance gets `sitl.RUN_PARAMS` (ADS-B on) on top of its defaults. The camera is on their
    SERIAL0, which starts their clocks together.
    """
    binary = sitl.find_binary(opts.sitl_binary)
    defaults = sitl.find_defaults(binary, opts.sitl_defaults)
    for i in range(mission.n_uavs):
        home = opts.out / f"sitl{i}"
        home.mkdir(exist_ok=True)
        argv = sitl.sitl_argv(binary, defaults, mission, i, opts.speedup, sitl.write_run_params(home))
        children.start(f"sitl{i}", argv, opts.out / f"sitl{i}.log", cwd=home, stop_signal=sitl.STOP_SIGNAL)
    ports = [sitl.sitl_ports(mission, i) for i in range(mission.n_uavs)]
    signing = mavlink_secrets(mission) is not None
    _start_camera(children, opts, [p.url(p.serial0) for p in ports], seed, mission.n_uavs, signing)
    return [p.url(p.serial1) for p in ports]


def _start_px4(children: Children, opts: RunOptions, mission: Mission, seed: int) -> list[str]:
    """One PX4 SITL per UAV and the stand-alone camera; returns the companions' links.

    Each SITL has its own working directory, made afresh; the camera is on their camera links.
    """
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
    """The bundled simulator; returns once it serves every vehicle."""
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
    """What went wrong if a vehicle, the camera or the router exited, or a companion refused to fly.

    A refusal is exit code 2; a companion that stops otherwise leaves the others flying.
    """
    for name, proc in children.procs.items():
        rc = proc.poll()
        if rc is None or (name.startswith("companion") and rc != 2):
            continue
        log = children.logs[name]
        last = [line for line in log.read_text(errors="replace").splitlines() if line.startswith("error:")]
        return f"{name} exited with code {rc}: {last[-1] if last else f'see {log}'}"
    return None


def security_summary(mission: Mission) -> str:
    """What authenticates this run, after checking that every identity's keys load.

    When nothing does, it is the insecure warning.
    """
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
    problem = check_options(opts, mission)
    if problem:
        print(f"error: {problem}", file=sys.stderr)
        return 2
    security = security_summary(mission)  # raises KeyDirectoryError (a ValueError) for bad keys
    print(security, flush=True)
    seed = mission.seed if opts.seed is None else opts.seed
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
        _start_swarm(children, opts, mission, seed)
        targets = truth_cells(out / "truth.json")
        progress = Progress(world, world.grid.centres[targets], started)
        failure = _watch(children, opts, logs, progress, stop, targets)
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
    return report_run(opts, mission, world, logs, seed, run, started, stop.is_set())


def _confirmed(out: Path, world: World, targets: np.ndarray) -> bool:
    """Whether the companions' target logs confirm every target (always, with a perfect sensor)."""
    if world.sensor.perfect:
        return True
    confirmed = {r.cell for r in read_target_logs(out, world.mission.n_uavs) if r.event == "confirmed"}
    return confirmed >= set(targets.tolist())


def _start_swarm(children: Children, opts: RunOptions, mission: Mission, seed: int) -> None:
    """Start the router (client-mode mesh), the vehicles, the live map and the companions.

    Each starts once it can; the call returns when the swarm flies.
    """
    out = opts.out
    if mission.mesh.mode == "client":
        children.start(
            "router",
            [sys.executable, "-m", "companion.cli", "router", "--mission", str(opts.mission_file)],
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
        argv = [sys.executable, "-m", "companion.cli", "view", "--mission", str(opts.mission_file)]
        argv += ["--seed", str(seed), "--port", str(opts.view_port)]
        children.start("view", argv, out / "view.log")
        line = children.wait_for_line("view", "view at ")
        print(f"live map of the swarm: {line.split('view at ', 1)[1]}", flush=True)
    steps = opts.steps or mission.steps
    for i in range(mission.n_uavs):
        argv = _companion_argv(opts, i, steps, seed, urls[i])
        if opts.vehicles and mavlink_secrets(mission) is not None:  # not ours to provision: their key
            argv += ["--mavlink-key", str(Path(mission.security.keys) / uav_identity(i) / "mavlink.key")]
        children.start(f"companion{i}", argv, out / f"companion{i}.log")
    if not opts.external:
        for i in range(mission.n_uavs):  # companions first: each waits for its vehicle's heartbeat
            children.wait_for_line(f"companion{i}", "waiting for the vehicle")
        _start_bundled(children, opts, mission, seed)


def _watch(
    children: Children,
    opts: RunOptions,
    logs: CompanionLogs,
    progress: Progress,
    stop: threading.Event,
    targets: np.ndarray,
) -> str | None:
    """Follow the flight until it ends; returns what went wrong, if anything did.

    The flight ends when every target is found (unless `keep_going`), every companion has exited
    or a signal comes. With an imperfect sensor a target is found once some companion confirmed it
    (its target log), not when it was in view.
    """
    last_print = 0.0
    while not stop.is_set():
        time.sleep(0.5)
        line = progress.update(logs.logs, logs.poll(), time.monotonic())
        if opts.progress and line is not None and time.monotonic() - last_print >= 2.0:
            print(line, flush=True)
            last_print = time.monotonic()
        companions = [p for n, p in children.procs.items() if n.startswith("companion")]
        found = progress.seen.all() and _confirmed(opts.out, progress.world, targets)
        all_found = found and not opts.keep_going
        if all_found or all(p.poll() is not None for p in companions):
            return None
        failure = _stopped_early(children)
        if failure:
            return failure
    return None
