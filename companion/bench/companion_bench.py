"""Benchmark of the companion: step latency, and the largest swarm that keeps real time.

`uavsearch companion-bench` (or `bench_main(argv)`, or `python -m companion.bench`) measures:

1. **Step latency** (observation in to command out) of the 4 UAVs of a mission: one process per
   UAV, each with a real Zenoh peer session and the real `Agent`, stepping in lockstep (each step
   waits, untimed, until every peer's bundle of the previous step is held). The timed part is
   what `Pilot.step` does once the pose and camera frame are in: `Mesh.inbox` + `Agent.step`
   + `Mesh.publish` + packing the MAVLink command (SET_ATTITUDE_TARGET, the default turn-rate
   mode). Poses advance with the core's `Kinematics` and detections come from the batch engine's
   targets, so the swarm flies as in the batch engine.
   With `--viewer` the same run is repeated with a viewer attached: `uavsearch view`'s live
   server on the mesh (`viewer` mode of this module) and a headless Chromium showing its page.
   With `--secured` it is repeated on a secured mesh (keys made for the run: TLS with mutual
   authentication, access control, every bundle signed and checked; docs/reliability.md).
2. **Largest real-time swarm**: N UAVs built from the mission (vehicles on a grid over the region,
   a unique key prefix, free ports), each stepping on the wall clock once per step period, in peer
   mode and in client mode with one router (`python -m companion.node.mesh router`). N grows over
   `--sizes` until a trial fails the criterion of `realtime_verdict`.

Worker processes are started with `subprocess` (never forked after Zenoh is opened), talk to this
process over JSON lines on stdin/stdout, are reused from trial to trial (a new Mesh per trial)
and are stopped by PID at the end. Only 127.0.0.1 is used; multicast scouting is off.
See docs/performance.md ("Companion").
"""

from __future__ import annotations

import argparse
import json
import math
import os
import queue
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any

import msgspec
import numpy as np

from companion.contracts.arguments import HelpFormatter
from companion.contracts.mission import Mission, Vehicle
from companion.core.feasibility import load_mission

DEFAULT_MISSION = Path(__file__).resolve().parents[2] / "mission_files" / "scenario1.toml"
# Fewer Zenoh runtime threads per process: many sessions share 2 cores (../shared/notes/zenoh.md).
LEAN_ZENOH_RUNTIME = (
    "(rx: (handover: app), net: (handover: app), acc: (handover: app), "
    "app: (worker_threads: 1), tx: (worker_threads: 1))"
)
TAG = "@@bench "  # prefix of the workers' protocol lines on stdout
STARTUP_S = 300.0  # a loaded 2-core machine imports numpy, numba and zenoh slowly, 50 times over
ALIVE_S = 120.0  # how long a worker waits to see every peer's liveliness token
PEER_WAIT_S = 30.0  # lockstep: how long a step waits for the peers' bundles
LATENCY_TARGET_MS = 5.0
# real-time criterion (see realtime_verdict)
P99_SHARE = 0.5
MISSING_SHARE = 0.01


# -- missions --------------------------------------------------------------------------------------
def free_tcp_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def spread_vehicles(mission: Mission, n: int) -> list[Vehicle]:
    """n vehicles on a square grid centred in the region, on cell centres, heading north.

    Spacing: at most 400 m (well inside R_c = 1000 m, so the swarm starts connected) and at most
    the region's width over the grid's side (50 UAVs: ~260 m, far above R_s = 60 m).
    """
    from companion.core.world import build_grid  # local: keep the parent light

    grid = build_grid(mission)
    xs = [p[0] for p in mission.region.polygon]
    ys = [p[1] for p in mission.region.polygon]
    cx, cy = (min(xs) + max(xs)) / 2, (min(ys) + max(ys)) / 2
    side = math.ceil(math.sqrt(n))
    width = 0.9 * min(max(xs) - min(xs), max(ys) - min(ys))
    spacing = min(400.0, width / max(1, side - 1))
    out = []
    for i in range(n):
        x = cx + spacing * (i % side - (side - 1) / 2)
        y = cy + spacing * (i // side - (side - 1) / 2)
        x = grid.x0 + grid.cell_size * round((x - grid.x0) / grid.cell_size)
        y = grid.y0 + grid.cell_size * round((y - grid.y0) / grid.cell_size)
        out.append(Vehicle(x=float(x), y=float(y), heading_deg=90.0))
    return out


def bench_mission(base: Mission, n: int | None, mode: str, tag: str, keys: Path | None = None) -> Mission:
    """`base` with n spread vehicles (None: its own), the mesh in `mode`, a unique key prefix,
    fresh loopback ports for the seed endpoint and the router and, with `keys`, secured by them."""
    vehicles = base.vehicles if n is None else spread_vehicles(base, n)
    mesh = msgspec.structs.replace(
        base.mesh,
        mode=mode,
        key_prefix=f"cbench{os.getpid()}{tag}",
        seed_endpoint=f"tcp/127.0.0.1:{free_tcp_port()}",
        router=f"tcp/127.0.0.1:{free_tcp_port()}",
        listen="tcp/127.0.0.1:0",
    )
    security = msgspec.structs.replace(base.security, keys=str(keys) if keys else "")
    return msgspec.structs.replace(base, vehicles=vehicles, mesh=mesh, security=security)


# -- worker side (one process per UAV) -------------------------------------------------------------
class _Uav:
    """One UAV's companion without the vehicle: Agent + Mesh, poses advanced with Kinematics."""

    def __init__(self, mission: Mission, uav: int) -> None:
        from pymavlink.dialects.v20 import ardupilotmega as mavlink

        from companion.core.agent import Agent
        from companion.core.prior import draw_targets
        from companion.core.world import Stream, build_world, instance_rng
        from companion.node.vehicle_link import COMPANION_COMPONENT

        self.mission, self.uav = mission, uav
        self.world = build_world(mission, mission.seed, 0)
        self.agent = Agent(self.world, uav)
        targets = draw_targets(
            self.world.prior, mission.prior.targets, instance_rng(mission.seed, 0, Stream.TARGETS)
        )
        self.targets = self.world.grid.centres[targets]
        self.r_a2 = self.world.grid.fov_radius2
        v = mission.vehicles[uav]
        self.pose = (float(v.x), float(v.y), math.radians(v.heading_deg))
        self.previous = (float(v.x), float(v.y))
        self.mavlink = mavlink
        self.mav = mavlink.MAVLink(None, srcSystem=255, srcComponent=COMPANION_COMPONENT)
        self.ignore = (
            mavlink.ATTITUDE_TARGET_TYPEMASK_BODY_ROLL_RATE_IGNORE
            | mavlink.ATTITUDE_TARGET_TYPEMASK_BODY_PITCH_RATE_IGNORE
            | mavlink.ATTITUDE_TARGET_TYPEMASK_THROTTLE_IGNORE
            | mavlink.ATTITUDE_TARGET_TYPEMASK_ATTITUDE_IGNORE
        )

    def detections(self) -> tuple[tuple[float, float], ...]:
        x, y, _ = self.pose
        d2 = np.sum((self.targets - np.array([x, y])) ** 2, axis=-1)
        return tuple(map(tuple, self.targets[d2 <= self.r_a2].tolist()))

    def command_bytes(self, heading_rate: float) -> bytes:
        """SET_ATTITUDE_TARGET with the body yaw rate, as `link.commands.turn_rate` sends it."""
        msg = self.mavlink.MAVLink_set_attitude_target_message(
            0,
            1,
            self.mavlink.MAV_COMP_ID_AUTOPILOT1,
            self.ignore,
            [1.0, 0.0, 0.0, 0.0],
            0.0,
            0.0,
            -heading_rate,
            0.0,
        )
        return msg.pack(self.mav)

    def step(self, mesh: Any, k: int) -> tuple[float, float, float, float]:
        """One companion step; returns the seconds of (inbox, agent, publish, mavlink)."""
        from companion.core.agent import Observation

        x, y, heading = self.pose
        obs = Observation(step=k, x=x, y=y, heading=heading, detections=self.detections())
        t0 = time.perf_counter()
        inbox = mesh.inbox(k, self.previous)
        t1 = time.perf_counter()
        command, outbox = self.agent.step(obs, inbox)
        t2 = time.perf_counter()
        mesh.publish(k, outbox, position=(x, y))
        t3 = time.perf_counter()
        self.command_bytes(command.heading_rate)
        t4 = time.perf_counter()
        self.previous = (x, y)
        nx, ny, nh = self.world.kinematics.advance(x, y, heading, command.turn)
        self.pose = (float(nx), float(ny), float(nh))
        return t1 - t0, t2 - t1, t3 - t2, t4 - t3


def _warm_up(mission: Mission, uav: int) -> None:
    """Load the numba caches and first-call paths: two throwaway agents exchange a few steps."""
    from companion.core.agent import Agent, Observation
    from companion.core.world import build_world

    world = build_world(mission, mission.seed, 0)
    ids = [uav, (uav + 1) % mission.n_uavs] if mission.n_uavs > 1 else [uav]
    agents = [Agent(world, i) for i in ids]
    poses = [(mission.vehicles[i].x, mission.vehicles[i].y, math.radians(90.0)) for i in ids]
    boxes: list[list[Any]] = [[] for _ in ids]
    for k in range(3):
        out = [
            a.step(Observation(step=k, x=p[0], y=p[1], heading=p[2]), box)
            for a, p, box in zip(agents, poses, boxes, strict=True)
        ]
        boxes = [[m for j, (_, ob) in enumerate(out) if j != i for m in ob] for i in range(len(ids))]
        poses = [
            tuple(float(v) for v in world.kinematics.advance(*p, c.turn))  # type: ignore[misc]
            for p, (c, _) in zip(poses, out, strict=True)
        ]


def signing_cost(mission: Mission, steps: int = 60) -> dict[str, float]:
    """Microseconds per bundle to sign (`Authenticator.relayable` + `seal`) and to check (`check`,
    each receiver keeping its checked signatures, as the mesh does): the mission's agents step
    together in one process, everyone hearing everyone, and every outbox is sealed by its sender
    and checked by every other UAV. `mission` must name a key directory."""
    from companion.contracts.keys import for_mission, uav_identity
    from companion.core.agent import Agent, Observation
    from companion.core.world import build_world
    from companion.node.mesh import Bundle, encode_bundle, key_base
    from companion.node.signing import Authenticator, decode_envelope

    world = build_world(mission, mission.seed, 0)
    n = mission.n_uavs
    auths = []
    for i in range(n):
        keys = for_mission(mission, uav_identity(i))
        assert keys is not None, "signing_cost needs a mission with keys"
        auths.append(Authenticator(keys.public, key_base(mission), keys.signing))
    agents = [Agent(world, i) for i in range(n)]
    poses = [(v.x, v.y, math.radians(v.heading_deg)) for v in mission.vehicles]
    boxes: list[list[Any]] = [[] for _ in range(n)]
    seal_us: list[float] = []
    check_us: list[float] = []
    for k in range(steps):
        out = [
            a.step(Observation(step=k, x=p[0], y=p[1], heading=p[2]), box)
            for a, p, box in zip(agents, poses, boxes, strict=True)
        ]
        boxes = [[] for _ in range(n)]
        for i, (_, outbox) in enumerate(out):
            t0 = time.perf_counter()
            msgs = auths[i].relayable(outbox)
            bundle = Bundle(sender=i, stamp=k, x=poses[i][0], y=poses[i][1], messages=tuple(msgs))
            wire = auths[i].seal(encode_bundle(bundle), bundle.messages)
            seal_us.append(1e6 * (time.perf_counter() - t0))
            envelope = decode_envelope(wire)
            for j in range(n):
                if j != i:
                    t0 = time.perf_counter()
                    auths[j].check(envelope, i, bundle.messages)
                    check_us.append(1e6 * (time.perf_counter() - t0))
                    boxes[j].extend(msgs)
        poses = [
            tuple(float(v) for v in world.kinematics.advance(*p, c.turn))  # type: ignore[misc]
            for p, (c, _) in zip(poses, out, strict=True)
        ]
    return {
        "seal_us_median": float(np.median(seal_us)),
        "check_us_median": float(np.median(check_us)),
        "bundles": len(seal_us),
    }


def _run(uav: _Uav, mesh: Any, peers: set[int], steps: int, period: float, start: float) -> dict:
    """The timed loop: lockstep when period == 0, else one step every `period` s from `start`."""
    phases = np.zeros((steps, 4))
    lag = np.zeros(steps)
    missing = 0
    while time.time() < start:
        time.sleep(min(0.05, max(0.0, start - time.time())))
    cpu0, wall0 = time.process_time(), time.perf_counter()
    for k in range(steps):
        due = start + k * period
        if period > 0:
            time.sleep(max(0.0, due - time.time()))
            if k > 0:
                missing += len(mesh.wait_for(k - 1, peers, 0.0))  # peers' bundles not in yet
        elif k > 0:
            missing += len(mesh.wait_for(k - 1, peers, PEER_WAIT_S))
        phases[k] = uav.step(mesh, k)
        lag[k] = time.time() - due
    cpu, wall = time.process_time() - cpu0, time.perf_counter() - wall0
    return {
        "uav": uav.uav,
        "phases_ms": (phases * 1e3).round(4).tolist(),
        "lag_ms": (lag * 1e3).round(4).tolist(),
        "missing": missing,
        "cpu_s": cpu,
        "wall_s": wall,
        "stats": asdict(mesh.stats),
    }


def _reply(**fields: object) -> None:
    sys.stdout.write(TAG + json.dumps(fields) + "\n")
    sys.stdout.flush()


def worker_main(argv: Sequence[str] | None = None) -> int:
    """A pool worker: JSON commands on stdin (open, go, close), replies on stdout; exits on EOF."""
    from companion.contracts.keys import for_mission, uav_identity
    from companion.node.mesh import Mesh

    _reply(op="hello", pid=os.getpid())
    mesh: Mesh | None = None
    uav: _Uav | None = None
    peers: set[int] = set()
    spec: dict = {}
    try:
        for line in sys.stdin:
            cmd = json.loads(line)
            op = cmd["op"]
            if op == "open":
                spec = cmd
                mission = msgspec.json.decode(Path(cmd["mission"]).read_bytes(), type=Mission)
                started = time.perf_counter()
                _warm_up(mission, cmd["uav"])
                uav = _Uav(mission, cmd["uav"])
                n_tasks = uav.world.tessellation.n_tasks if uav.world.tessellation else 0
                keys = for_mission(mission, uav_identity(cmd["uav"]))
                mesh = Mesh(mission, cmd["uav"], uav.world.grid.n_cells, n_tasks, keys=keys)
                peers = set(range(mission.n_uavs)) - {cmd["uav"]}
                absent = mesh.wait_alive(peers, ALIVE_S)
                _reply(op="ready", missing=sorted(absent), open_s=time.perf_counter() - started)
            elif op == "go":
                assert mesh is not None and uav is not None
                result = _run(uav, mesh, peers, spec["steps"], spec["period"], cmd["start"])
                _reply(op="result", **result)
            elif op == "close":
                if mesh is not None:
                    mesh.close()
                mesh, uav = None, None
                _reply(op="closed")
    finally:
        if mesh is not None:
            mesh.close()
    return 0


def viewer_main(argv: Sequence[str]) -> int:
    """The view's live server on a trial's mesh (`python -m companion.bench viewer MISSION.json`):
    prints its URL as a protocol line, serves until SIGINT/SIGTERM."""
    from companion.app.view.main import warm_kernels
    from companion.app.view.server import LiveSource, serve
    from companion.contracts.keys import for_mission
    from companion.core.world import build_world

    mission = msgspec.json.decode(Path(argv[0]).read_bytes(), type=Mission)
    warm_kernels()
    source = LiveSource(build_world(mission, mission.seed, 0), mission.seed, for_mission(mission, "view"))
    serve(source, "127.0.0.1", 0, lambda address: _reply(op="view", url=address.url, pid=os.getpid()))
    return 0


# -- parent side -----------------------------------------------------------------------------------
CHROMIUM = Path("/usr/bin/chromium")
CHROMIUM_FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
)


class _Viewer:
    """A viewer on a trial's mesh: the view server, and a headless Chromium on its page (when
    /usr/bin/chromium exists). Both stopped by PID."""

    def __init__(self, mission_json: Path, log: Path) -> None:
        self.log = log
        with log.open("w") as err:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "companion.bench", "viewer", str(mission_json)],
                stdout=subprocess.PIPE,
                stderr=err,
                text=True,
            )
        assert self.proc.stdout is not None
        self.url = ""
        for line in self.proc.stdout:
            if line.startswith(TAG):
                self.url = json.loads(line[len(TAG) :])["url"]
                break
        if not self.url:
            self.stop()
            raise RuntimeError(f"the view server did not start: {log.read_text(errors='replace')[-500:]}")
        self.browser: subprocess.Popen | None = None
        self._profile = tempfile.TemporaryDirectory(prefix="companion-bench-chromium-")
        if CHROMIUM.exists():
            self.browser = subprocess.Popen(
                [str(CHROMIUM), *CHROMIUM_FLAGS, f"--user-data-dir={self._profile.name}", self.url],
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
            )

    def status(self) -> dict:
        with urllib.request.urlopen(self.url + "api/status", timeout=10) as r:
            return json.load(r)

    def wait_attached(self, n: int, timeout: float) -> dict:
        """Until the server sees all n UAVs alive and (with a browser) the page is connected."""
        deadline = time.monotonic() + timeout
        while True:
            s = self.status()
            if len(s["alive"]) == n and (self.browser is None or s["pages"] >= 1):
                return s
            if time.monotonic() > deadline:
                raise RuntimeError(f"viewer not attached within {timeout:.0f} s: {s}")
            time.sleep(0.2)

    def cpu_s(self) -> float:
        """CPU seconds of the view server and of the browser with all its processes."""
        browser = _tree_cpu_s(self.browser.pid) if self.browser else 0.0
        return _proc_cpu_s(self.proc.pid) + browser

    def stop(self) -> None:
        if self.browser is not None:
            self.browser.terminate()
            _reap(self.browser)
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
        _reap(self.proc)
        self._profile.cleanup()


class _Worker:
    """A worker subprocess; a thread turns its protocol lines into a queue."""

    def __init__(self, env: dict[str, str], log: Path) -> None:
        self.log = log
        with log.open("w") as err:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "companion.bench", "worker"],
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                stderr=err,
                text=True,
                env=env,
            )
        self.lines: queue.Queue[dict | None] = queue.Queue()
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            if line.startswith(TAG):
                self.lines.put(json.loads(line[len(TAG) :]))
        self.lines.put(None)

    def send(self, **cmd: object) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write(json.dumps(cmd) + "\n")
        self.proc.stdin.flush()

    def recv(self, op: str, timeout: float) -> dict:
        try:
            msg = self.lines.get(timeout=timeout)
        except queue.Empty:
            raise RuntimeError(f"worker {self.proc.pid}: no {op!r} within {timeout:.0f} s") from None
        if msg is None:
            self.proc.wait(timeout=15)
            tail = self.log.read_text(errors="replace").strip().splitlines()[-3:]
            raise RuntimeError(f"worker {self.proc.pid} exited (code {self.proc.poll()}): {' | '.join(tail)}")
        if msg.get("op") != op:
            raise RuntimeError(f"worker {self.proc.pid}: expected {op!r}, got {msg.get('op')!r}")
        return msg

    def stop(self) -> None:
        """Close stdin (the worker closes its session and exits); kill by PID if it lingers."""
        try:
            if self.proc.stdin is not None:
                self.proc.stdin.close()
        except OSError:
            pass
        _reap(self.proc)


def _reap(proc: subprocess.Popen) -> None:
    """Wait for a process we asked to stop; kill it by PID if it lingers; close its pipe."""
    try:
        proc.wait(timeout=15)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(timeout=15)
    if proc.stdout is not None:
        proc.stdout.close()


class _Pool:
    """Workers started on demand and reused across trials."""

    def __init__(self, lean_runtime: bool) -> None:
        self.env = dict(os.environ)
        if lean_runtime:
            self.env["ZENOH_RUNTIME"] = LEAN_ZENOH_RUNTIME
        self.workers: list[_Worker] = []
        self._logs = tempfile.TemporaryDirectory(prefix="companion-bench-logs-")

    def take(self, n: int) -> list[_Worker]:
        logs = Path(self._logs.name)
        new = [_Worker(self.env, logs / f"worker{i}.log") for i in range(len(self.workers), n)]
        self.workers.extend(new)
        for w in new:
            w.recv("hello", STARTUP_S)
        return self.workers[:n]

    def close(self) -> None:
        for w in self.workers:
            w.stop()
        self.workers.clear()
        self._logs.cleanup()


class _Router:
    """`python -m companion.node.mesh router --endpoint E` in its own process, stopped with SIGTERM."""

    def __init__(self, endpoint: str) -> None:
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "companion.node.mesh", "router", "--endpoint", endpoint],
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
            text=True,
        )
        assert self.proc.stdout is not None
        line = self.proc.stdout.readline()  # "router listening on E"
        if "listening" not in line:
            self.stop()
            raise RuntimeError(f"router did not start on {endpoint}")

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
        _reap(self.proc)


def _proc_cpu_s(pid: int) -> float:
    """User + system CPU seconds of a process (0 if gone)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return 0.0
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _tree_cpu_s(pid: int) -> float:
    """CPU seconds of a live process and all its live descendants."""
    parents: dict[int, int] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                parents[int(entry.name)] = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, ValueError, IndexError):
                continue
    tree, grew = {pid}, True
    while grew:
        new = {p for p, parent in parents.items() if parent in tree and p not in tree}
        tree |= new
        grew = bool(new)
    return sum(_proc_cpu_s(p) for p in tree)


def _machine_ticks() -> tuple[int, int]:
    """(busy, total) jiffies over all CPUs from /proc/stat."""
    values = [int(v) for v in Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]]
    idle = values[3] + (values[4] if len(values) > 4 else 0)
    return sum(values) - idle, sum(values)


def machine_load(seconds: float = 2.0) -> dict[str, float]:
    """How busy the machine is before we start: cores busy over `seconds`, and the load average."""
    b0, t0 = _machine_ticks()
    time.sleep(seconds)
    b1, t1 = _machine_ticks()
    cores = os.cpu_count() or 1
    return {"cores": cores, "busy_cores": cores * (b1 - b0) / max(1, t1 - t0), "loadavg": os.getloadavg()[0]}


def _pct(values: np.ndarray | list[float], q: float) -> float:
    return float(np.percentile(values, q)) if len(values) else math.nan


def trial(pool: _Pool, mission: Mission, steps: int, period: float, tmp: Path, viewer: bool = False) -> dict:
    """Run one trial (lockstep when period == 0) on mission.n_uavs workers; the raw figures.
    With `viewer`, a `_Viewer` watches the mesh from before the first step to after the last."""
    n = mission.n_uavs
    path = tmp / f"{mission.mesh.key_prefix}.json"
    path.write_bytes(msgspec.json.encode(mission))
    workers = pool.take(n)
    router = _Router(mission.mesh.router) if mission.mesh.mode == "client" else None
    watcher: _Viewer | None = None
    seen: dict = {}
    try:
        for i, w in enumerate(workers):
            w.send(op="open", mission=str(path), uav=i, steps=steps, period=period)
        ready = [w.recv("ready", ALIVE_S + 120) for w in workers]
        absent = sum(len(r["missing"]) for r in ready)
        if viewer:
            watcher = _Viewer(path, tmp / f"{mission.mesh.key_prefix}-viewer.log")
            watcher.wait_attached(n, STARTUP_S)
        start = time.time() + 1.0
        b0, t0 = _machine_ticks()
        r0 = _proc_cpu_s(router.proc.pid) if router else 0.0
        v0 = watcher.cpu_s() if watcher else 0.0
        for w in workers:
            w.send(op="go", start=start)
        budget = steps * (period or 1.0) + 120
        results = [w.recv("result", budget) for w in workers]
        b1, t1 = _machine_ticks()
        r1 = _proc_cpu_s(router.proc.pid) if router else 0.0
        v1 = watcher.cpu_s() if watcher else 0.0
        if watcher is not None:
            time.sleep(1.0)  # the last step closes on the viewer
            seen = {**watcher.status(), "cpu_s": v1 - v0, "browser": watcher.browser is not None}
        for w in workers:
            w.send(op="close")
        for w in workers:
            w.recv("closed", 60)
    finally:
        if watcher is not None:
            watcher.stop()
        if router is not None:
            router.stop()
        path.unlink(missing_ok=True)
    wall = max(r["wall_s"] for r in results)
    cores = os.cpu_count() or 1
    return {
        "n": n,
        "mode": mission.mesh.mode,
        "steps": steps,
        "period": period,
        "absent_at_start": absent,
        "results": results,
        "swarm_cores": sum(r["cpu_s"] for r in results) / wall,
        "router_cores": (r1 - r0) / wall,
        "machine_busy_cores": cores * (b1 - b0) / max(1, t1 - t0),
        "viewer": {**seen, "cores": seen["cpu_s"] / wall, "cpu_ms_per_step": 1e3 * seen["cpu_s"] / steps}
        if seen
        else None,
    }


def _stats_sum(t: dict, key: str) -> int:
    return sum(r["stats"][key] for r in t["results"])


def summarize(t: dict) -> dict:
    """Per-UAV and overall figures of a trial (milliseconds)."""
    per_uav = []
    every = []
    for r in t["results"]:
        ph = np.array(r["phases_ms"]).reshape(-1, 4)
        total = ph.sum(axis=1)
        every.append(total)
        per_uav.append(
            {
                "uav": r["uav"],
                "p50": _pct(total, 50),
                "p99": _pct(total, 99),
                "max": float(total.max()) if len(total) else math.nan,
                "median_phases": dict(
                    zip(("inbox", "agent", "publish", "mavlink"), np.median(ph, axis=0).tolist(), strict=True)
                ),
            }
        )
    allv = np.concatenate(every) if every else np.zeros(0)
    lag = np.concatenate([np.array(r["lag_ms"]) for r in t["results"]])
    n, steps = t["n"], t["steps"]
    return {
        "n": n,
        "mode": t["mode"],
        "period_s": t["period"],
        "steps": steps,
        "per_uav": per_uav,
        "latency_ms": {"p50": _pct(allv, 50), "p99": _pct(allv, 99), "max": float(allv.max())},
        "lag_ms": {"p50": _pct(lag, 50), "p99": _pct(lag, 99), "max": float(lag.max())},
        "overruns": int(np.count_nonzero(lag > 1e3 * t["period"])) if t["period"] > 0 else 0,
        "missing": sum(r["missing"] for r in t["results"]),
        "expected": n * (n - 1) * max(0, steps - 1),
        "absent_at_start": t["absent_at_start"],
        "stale": _stats_sum(t, "stale"),
        "lost": _stats_sum(t, "lost"),
        "malformed": _stats_sum(t, "malformed"),
        "rejected": sum(_stats_sum(t, k) for k in ("spoofed", "unauthenticated", "forged")),
        "received": _stats_sum(t, "received"),
        "swarm_cores": t["swarm_cores"],
        "router_cores": t["router_cores"],
        "machine_busy_cores": t["machine_busy_cores"],
        "viewer": t.get("viewer"),
    }


def realtime_verdict(s: dict) -> tuple[bool, str]:
    """The real-time criterion. With T the step period, "lag" a step's completion time (end of
    inbox -> step -> publish -> MAVLink command) minus its scheduled start k*T, a trial passes iff

    1. every UAV saw all N-1 peers alive before the start and finished every step;
    2. no overrun: lag <= T for every UAV and every step;
    3. p99 of lag over all UAVs and steps <= 0.5 T;
    4. delivery: the peers' step k-1 bundles not yet held when step k starts, and the stale
       bundles (arriving after their step), each <= 1 % of the N(N-1)(steps-1) expected; no
       malformed bundle and no lost message.
    """
    period_ms = 1e3 * s["period_s"]
    limit = MISSING_SHARE * max(1, s["expected"])
    problems = []
    if s["absent_at_start"]:
        problems.append(f"{s['absent_at_start']} peer sightings missing at start")
    if s["overruns"]:
        problems.append(f"{s['overruns']} overruns")
    if s["lag_ms"]["p99"] > P99_SHARE * period_ms:
        problems.append(f"lag p99 {s['lag_ms']['p99']:.0f} ms > {P99_SHARE * period_ms:.0f} ms")
    if s["missing"] > limit:
        problems.append(f"{s['missing']} late bundles")
    if s["stale"] > limit:
        problems.append(f"{s['stale']} stale bundles")
    if s["malformed"] or s["lost"]:
        problems.append(f"{s['malformed']} malformed, {s['lost']} lost")
    return not problems, "; ".join(problems) or "ok"


def _fmt_latency(s: dict) -> list[str]:
    lines = []
    for u in s["per_uav"]:
        ph = u["median_phases"]
        lines.append(
            f"  uav {u['uav']}: p50 {u['p50']:.2f} ms  p99 {u['p99']:.2f} ms  max {u['max']:.2f} ms"
            f"   (medians: inbox {ph['inbox']:.3f}, agent {ph['agent']:.2f}, publish {ph['publish']:.3f},"
            f" mavlink {ph['mavlink']:.3f} ms)"
        )
    a = s["latency_ms"]
    verdict = "meets" if a["p99"] < LATENCY_TARGET_MS else "MISSES"
    lines.append(
        f"  all:   p50 {a['p50']:.2f} ms  p99 {a['p99']:.2f} ms  max {a['max']:.2f} ms"
        f"   ({verdict} the target p99 < {LATENCY_TARGET_MS:g} ms)"
    )
    lines.append(
        f"  cpu: swarm {s['swarm_cores']:.2f} cores; machine busy {s['machine_busy_cores']:.2f} cores;"
        f" late bundles {s['missing']}, stale {s['stale']}, lost {s['lost']}"
    )
    return lines


def _fmt_trial(s: dict, verdict: tuple[bool, str]) -> str:
    lat, lag = s["latency_ms"], s["lag_ms"]
    router = f" + router {s['router_cores']:.2f}" if s["mode"] == "client" else ""
    return (
        f"  N={s['n']:>3}: {'PASS' if verdict[0] else 'FAIL'}  step p50/p99/max "
        f"{lat['p50']:.1f}/{lat['p99']:.1f}/{lat['max']:.1f} ms,"
        f" lag p99/max {lag['p99']:.0f}/{lag['max']:.0f} ms,"
        f" overruns {s['overruns']}, late {s['missing']}/{s['expected']}, stale {s['stale']},"
        f" lost {s['lost']}; cpu swarm {s['swarm_cores']:.2f}{router} cores,"
        f" machine busy {s['machine_busy_cores']:.2f} cores" + ("" if verdict[0] else f"  [{verdict[1]}]")
    )


def search(
    pool: _Pool, base: Mission, mode: str, sizes: list[int], steps: int, period: float, tmp: Path, tag: str
) -> tuple[int, list[dict]]:
    """Trials over increasing N until one fails; the largest passing N and every summary."""
    best, rows = 0, []
    print(f"real-time swarm, {mode} mode, step period {period:g} s, {steps} steps per trial:", flush=True)
    for n in sizes:
        mission = bench_mission(base, n, mode, f"{tag}{mode[0]}{n}")
        try:
            s = summarize(trial(pool, mission, steps, period, tmp))
            verdict = realtime_verdict(s)
        except RuntimeError as exc:
            s, verdict = {"n": n, "mode": mode, "period_s": period, "error": str(exc)}, (False, str(exc))
            print(f"  N={n:>3}: FAIL  [{exc}]", flush=True)
        else:
            print(_fmt_trial(s, verdict), flush=True)
        s["pass"], s["why"] = verdict
        rows.append(s)
        if not verdict[0]:
            break
        best = n
    print(f"  largest real-time swarm in {mode} mode at {period:g} s: {best} UAVs", flush=True)
    return best, rows


def bench_main(argv: Sequence[str] | None = None) -> int:
    """`uavsearch companion-bench`: print the figures (and write them as JSON with --json)."""
    parser = argparse.ArgumentParser(
        prog="uavsearch companion-bench",
        description="Companion step latency and the largest swarm that runs in real time.",
        formatter_class=HelpFormatter,
    )
    parser.add_argument("--mission", type=Path, default=DEFAULT_MISSION, help="the mission flown")
    parser.add_argument("--latency-steps", type=int, default=300, help="lockstep steps of the 4-UAV run")
    parser.add_argument("--sizes", default="4,10,20,30,50", help="swarm sizes tried, increasing")
    parser.add_argument("--modes", default="peer,client", help="mesh modes searched")
    parser.add_argument("--steps", type=int, default=20, help="steps per real-time trial")
    parser.add_argument("--period", type=float, help="real-time step period, s (default kinematics.step)")
    parser.add_argument(
        "--stress-period", type=float, default=0.0, help="also search at this faster period, s (0: no)"
    )
    parser.add_argument(
        "--default-runtime", action="store_true", help="do not set the lean ZENOH_RUNTIME for the UAVs"
    )
    parser.add_argument(
        "--viewer",
        action="store_true",
        help="repeat the latency run with a viewer attached (uavsearch view + headless Chromium)",
    )
    parser.add_argument(
        "--secured",
        action="store_true",
        help="repeat the latency run on a secured mesh (TLS, access control, signed bundles)",
    )
    parser.add_argument("--skip-latency", action="store_true", help="leave out the latency run")
    parser.add_argument("--skip-realtime", action="store_true", help="leave out the real-time swarm search")
    parser.add_argument("--json", type=Path, help="also write every figure to this file (default: none)")
    parser.add_argument("--quick", action="store_true", help="smoke run: tiny sizes and step counts")
    args = parser.parse_args(argv)
    if args.quick:
        args.latency_steps, args.sizes, args.steps = 10, "2,3", 4
        args.period = args.period or 0.5
        args.stress_period = 0.0
    try:
        base = load_mission(args.mission)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    period = args.period or base.kinematics.step
    sizes = sorted(int(s) for s in args.sizes.split(","))
    modes = [m for m in args.modes.split(",") if m]
    if any(m not in ("peer", "client") for m in modes) or args.latency_steps < 2 or args.steps < 2:
        parser.error("modes are peer and/or client; at least 2 steps")
    load = machine_load()
    print(
        f"machine: {load['cores']} cores, {load['busy_cores']:.2f} cores busy before start"
        f" (load average {load['loadavg']:.2f}); ZENOH_RUNTIME "
        f"{'default' if args.default_runtime else 'lean (1 app + 1 tx thread)'} in the UAV processes",
        flush=True,
    )
    report: dict[str, Any] = {"machine": load, "argv": list(argv or [])}
    pool = _Pool(lean_runtime=not args.default_runtime)
    started = time.monotonic()
    try:
        with tempfile.TemporaryDirectory(prefix="companion-bench-") as tmp:
            tag = f"q{int(time.time()) % 100000}"
            if not args.skip_latency:
                mission = bench_mission(base, None, "peer", f"{tag}lat")
                s = summarize(trial(pool, mission, args.latency_steps, 0.0, Path(tmp)))
                print(
                    f"step latency, observation in -> command out: {mission.n_uavs} UAVs of {base.name},"
                    f" peer mesh, lockstep, {args.latency_steps} steps",
                    flush=True,
                )
                print("\n".join(_fmt_latency(s)), flush=True)
                report["latency"] = s
                if args.viewer:
                    mission = bench_mission(base, None, "peer", f"{tag}latv")
                    s = summarize(trial(pool, mission, args.latency_steps, 0.0, Path(tmp), viewer=True))
                    v = s["viewer"]
                    print(
                        "the same with a viewer attached (uavsearch view's live server"
                        f"{' + headless Chromium on its page' if v['browser'] else ''}):",
                        flush=True,
                    )
                    print("\n".join(_fmt_latency(s)), flush=True)
                    print(
                        f"  viewer: {v['cpu_ms_per_step']:.2f} ms of CPU per step ({v['cores']:.2f} cores),"
                        f" {v['received']} bundles received,"
                        f" step {v['step']} drawn last, {v['malformed']} malformed, {v['late']} late",
                        flush=True,
                    )
                    report["latency_with_viewer"] = s
                if args.secured:
                    from companion.contracts.keys import generate

                    keys = Path(tmp) / "keys"
                    generate(keys, base.n_uavs)
                    mission = bench_mission(base, None, "peer", f"{tag}lats", keys)
                    s = summarize(trial(pool, mission, args.latency_steps, 0.0, Path(tmp)))
                    print(
                        "the same on a secured mesh (mutual TLS, access control, Ed25519-signed bundles"
                        f" checked on receipt); {s['received']} bundles received, {s['rejected']} rejected:",
                        flush=True,
                    )
                    print("\n".join(_fmt_latency(s)), flush=True)
                    report["latency_secured"] = s
                    cost = signing_cost(mission)
                    print(
                        f"  signing, per bundle of this swarm: sign {cost['seal_us_median']:.0f} us, check"
                        f" {cost['check_us_median']:.0f} us (medians over {cost['bundles']} bundles, one"
                        " process, every UAV hearing every other)",
                        flush=True,
                    )
                    report["signing_cost"] = cost
            if not args.skip_realtime:
                report["realtime"] = {}
                periods = [period] + ([args.stress_period] if args.stress_period > 0 else [])
                for p in periods:
                    for mode in modes:
                        best, rows = search(pool, base, mode, sizes, args.steps, p, Path(tmp), tag)
                        report["realtime"][f"{mode}@{p:g}"] = {"largest": best, "trials": rows}
                print(
                    "largest real-time swarm: "
                    + ", ".join(f"{k}s {v['largest']}" for k, v in report["realtime"].items()),
                    flush=True,
                )
    finally:
        pool.close()
    report["elapsed_s"] = time.monotonic() - started
    print(f"benchmark took {report['elapsed_s']:.0f} s", flush=True)
    if args.json is not None:
        args.json.write_text(json.dumps(report, indent=1) + "\n")
    return 0


def main() -> None:
    """`python -m companion.bench [worker] ...`."""
    if sys.argv[1:2] == ["worker"]:
        sys.exit(worker_main(sys.argv[2:]))
    if sys.argv[1:2] == ["viewer"]:
        sys.exit(viewer_main(sys.argv[2:]))
    sys.exit(bench_main(sys.argv[1:]))
