"""A benchmark worker process: one UAV's companion (Agent + Mesh) stepping as the parent says.

`python -m companion.bench worker` reads JSON commands on stdin (open, go, close) and answers with
protocol lines (TAG + JSON) on stdout; `python -m companion.bench viewer MISSION.json` serves the
view's live server on a trial's mesh. See docs/performance.md ("Companion").
"""

from __future__ import annotations

import json
import math
import os
import sys
import time
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import msgspec
import numpy as np

from companion.contracts.mission import Mission
from companion.node.mesh import MeshStats

TAG = "@@bench "  # prefix of the workers' protocol lines on stdout
ALIVE_S = 120.0  # how long a worker waits to see every peer's liveliness token
PEER_WAIT_S = 30.0  # lockstep: how long a step waits for the peers' bundles


class WorkerReady(msgspec.Struct, frozen=True):
    """A worker's "ready" reply: the peers it did not see alive, and the seconds `open` took."""

    missing: list[int]
    open_s: float


class UavRun(msgspec.Struct, frozen=True):
    """A worker's "result" reply: one UAV's timed steps.

    Per step the milliseconds of (inbox, agent, publish, mavlink) and the lag behind its scheduled
    start; the peers' bundles not yet held at a step's start; CPU and wall seconds; mesh counters."""

    uav: int
    phases_ms: list[list[float]]
    lag_ms: list[float]
    missing: int
    cpu_s: float
    wall_s: float
    stats: MeshStats


class UavCompanion:
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


def warm_up(mission: Mission, uav: int) -> None:
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



def run_steps(
    uav: UavCompanion, mesh: Any, peers: set[int], steps: int, period: float, start: float
) -> UavRun:
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
    return UavRun(
        uav=uav.uav,
        phases_ms=(phases * 1e3).round(4).tolist(),
        lag_ms=(lag * 1e3).round(4).tolist(),
        missing=missing,
        cpu_s=cpu,
        wall_s=wall,
        stats=replace(mesh.stats),  # a snapshot: the mesh keeps counting
    )


def reply(**fields: object) -> None:
    sys.stdout.write(TAG + json.dumps(fields) + "\n")
    sys.stdout.flush()


def worker_main(argv: Sequence[str] | None = None) -> int:
    """A pool worker: JSON commands on stdin (open, go, close), replies on stdout; exits on EOF."""
    from companion.contracts.keys import for_mission, uav_identity
    from companion.node.mesh import Mesh

    reply(op="hello", pid=os.getpid())
    mesh: Mesh | None = None
    uav: UavCompanion | None = None
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
                warm_up(mission, cmd["uav"])
                uav = UavCompanion(mission, cmd["uav"])
                n_tasks = uav.world.tessellation.n_tasks if uav.world.tessellation else 0
                keys = for_mission(mission, uav_identity(cmd["uav"]))
                mesh = Mesh(mission, cmd["uav"], uav.world.grid.n_cells, n_tasks, keys=keys)
                peers = set(range(mission.n_uavs)) - {cmd["uav"]}
                absent = mesh.wait_alive(peers, ALIVE_S)
                ready = WorkerReady(missing=sorted(absent), open_s=time.perf_counter() - started)
                reply(op="ready", **msgspec.to_builtins(ready))
            elif op == "go":
                assert mesh is not None and uav is not None
                result = run_steps(uav, mesh, peers, spec["steps"], spec["period"], cmd["start"])
                reply(op="result", **msgspec.to_builtins(result))
            elif op == "close":
                if mesh is not None:
                    mesh.close()
                mesh, uav = None, None
                reply(op="closed")
    finally:
        if mesh is not None:
            mesh.close()
    return 0


def viewer_main(argv: Sequence[str]) -> int:
    """The view's live server on a trial's mesh, until SIGINT/SIGTERM.

    The view's live server on a trial's mesh (`python -m companion.bench viewer MISSION.json`):
    prints its URL as a protocol line, serves until SIGINT/SIGTERM."""
    from companion.app.view.main import warm_kernels
    from companion.app.view.server import LiveSource, serve
    from companion.contracts.keys import for_mission
    from companion.core.world import build_world

    mission = msgspec.json.decode(Path(argv[0]).read_bytes(), type=Mission)
    warm_kernels()
    source = LiveSource(build_world(mission, mission.seed, 0), mission.seed, for_mission(mission, "view"))
    serve(source, "127.0.0.1", 0, lambda address: reply(op="view", url=address.url, pid=os.getpid()))
    return 0

