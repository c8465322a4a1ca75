"""The companion process: one per UAV, driving the core's Agent with real I/O.

Every sampling step k (vehicle time k * dT) it reads its vehicle's pose over MAVLink, takes the
camera's detections, takes the peers' step k-1 messages from the mesh, calls `Agent.step`, sends
the command to the vehicle in the chosen command mode (only while the vehicle is in its guided
mode) and publishes the outbox. The clock is the vehicle's: a sped-up simulator just works.

In lockstep the bundled simulator advances only when every companion has reported that its step
is done (MAV_CMD_USER_1, see docs/simulator.md), and each step waits for the pose, the camera frame
and the peers' messages of that step, so a distributed run reproduces the batch engine's.
"""

from __future__ import annotations

import csv
import json
import logging
import math
import threading
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from companion.batch.engine import warm_up
from companion.core.agent import Agent, Command, Observation
from companion.core.kinematics import arc_advance
from companion.core.world import build_world
from companion.mission import Mission
from companion.node.camera_feed import CameraFeed
from companion.node.detections import camera_key
from companion.node.frames import LocalFrame, heading_to_yaw
from companion.node.mesh import Mesh
from companion.node.vehicle_link import ARDUPILOT_GUIDED, PX4_HOLD, PX4_OFFBOARD, VehicleLink

log = logging.getLogger("companion")

COMMAND_MODES = ("turn-rate", "heading", "reposition", "position-target")
LOCKSTEP_COMMAND = 31010  # MAV_CMD_USER_1: "lockstep: ready for step param1"
# Guidance is streamed (vehicle seconds between repeats of the current command) so that the
# autopilot's guidance timeout never fires between steps; PX4 OFFBOARD needs more than 2 Hz.
STREAM_PERIOD_S = {"turn-rate": 0.5, "heading": 0.5, "position-target": 0.2}
# In real time a step is planned LEAD of a step before it starts, from the pose predicted for its
# start, so that the command is in place when the autopilot begins the step (no one-step lag).
LEAD = 0.25
LINK_TIMEOUT_S = 3.0  # wall seconds without HEARTBEAT before the link counts as lost
PEER_WAIT_S = 30.0  # lockstep: how long to wait for a live peer's messages before going on
TAKEOVER_TIMEOUT_S = 30.0  # wall seconds --takeover keeps trying to set the guided mode and arm
LEAD_STEPS, LEAD_MIN_M = 5, 200.0  # waypoint modes fly to a point this far ahead (see _lead_point)


@dataclass(frozen=True)
class CompanionOptions:
    mission: Mission
    uav: int
    vehicle_url: str
    command_mode: str = "turn-rate"
    takeover: bool = False
    lockstep: bool = False
    seed: int | None = None
    steps: int | None = None
    out: Path | None = None


def default_vehicle_url(mission: Mission, uav: int) -> str:
    """The bundled simulator's endpoint of vehicle `uav` (it listens; the companion sends first)."""
    return f"udpout:{mission.sim.host}:{mission.vehicle_port(uav)}"


class Companion:
    """The per-UAV loop; `run` returns when `stop` is set or the step budget is spent."""

    def __init__(self, opts: CompanionOptions, link: VehicleLink, mesh: Mesh, camera: CameraFeed) -> None:
        m = opts.mission
        self.opts, self.link, self.mesh, self.camera = opts, link, mesh, camera
        seed = m.seed if opts.seed is None else opts.seed
        self.world = build_world(m, seed, 0)
        self.agent = Agent(self.world, opts.uav)
        self.frame = LocalFrame(m.region.origin)
        self.dt = m.kinematics.step
        self.steps_done = 0
        self.last_position: np.ndarray | None = None
        self.steering = True
        self.last_command: Command | None = None
        self._last_send = -math.inf
        self._seen_alive: set[int] = set()
        self._departed: set[int] = set()
        self._rows: list[list[object]] = []
        self._log_file = None
        self._log = None
        if opts.out is not None:
            opts.out.mkdir(parents=True, exist_ok=True)
            self._log_file = (opts.out / f"uav{opts.uav}.csv").open("w", newline="")
            self._log = csv.writer(self._log_file)
            self._log.writerow(
                [
                    "step",
                    "time",
                    "x",
                    "y",
                    "heading",
                    "task",
                    "mean_eta",
                    "found",
                    "steered",
                    "turn",
                    "cmd_x",
                    "cmd_y",
                    "peers",
                ]
            )

    # -- vehicle ---------------------------------------------------------------------------------
    def _steerable(self) -> bool:
        s = self.link.state
        if s.px4:
            if self.opts.command_mode == "reposition":
                return s.custom_mode in (PX4_HOLD, PX4_OFFBOARD)
            return s.custom_mode == PX4_OFFBOARD
        return s.custom_mode == ARDUPILOT_GUIDED

    def _take_over(self, stop: threading.Event) -> None:
        """Switch the vehicle to its guided mode and arm it (only with --takeover), retrying until
        its HEARTBEAT shows both. PX4 refuses OFFBOARD without a setpoint stream (> 2 Hz): stream
        the current position first, and keep streaming while waiting."""
        s, link = self.link.state, self.link
        offboard = s.px4 and self.opts.command_mode != "reposition"
        want = (PX4_OFFBOARD if offboard else PX4_HOLD) if s.px4 else ARDUPILOT_GUIDED
        deadline = time.monotonic() + TAKEOVER_TIMEOUT_S
        sent, last_wall, last_try = 0, -math.inf, -math.inf
        while not stop.is_set() and not (self._steerable() and s.armed):
            now = time.monotonic()
            if now > deadline:
                log.warning("uav %d: takeover failed: not in the guided mode and armed", self.opts.uav)
                return
            period = STREAM_PERIOD_S["position-target"]
            if offboard and (s.time_s - self._last_send >= period or now - last_wall >= period):
                self._send_target_of(s.x, s.y)
                self._last_send, last_wall, sent = s.time_s, now, sent + 1
            if (not offboard or sent >= 3) and now - last_try >= 1.0:
                link.set_mode(want)
                link.arm()
                last_try = now
            link.poll(0.02)

    def _send_target_of(self, x: float, y: float) -> None:
        lat, lon, _ = self.frame.to_geodetic(x, y)
        self.link.position_target(lat, lon, self.opts.mission.kinematics.altitude)

    def _send(self, command: Command) -> None:
        mode, link = self.opts.command_mode, self.link
        if mode == "turn-rate":
            link.turn_rate(-command.heading_rate)  # MAVLink yaw rate is clockwise-positive
        elif mode == "heading":
            link.change_heading(math.degrees(heading_to_yaw(command.heading)))
        elif mode == "reposition":
            lat, lon, _ = self.frame.to_geodetic(*self._lead_point(command))
            link.reposition(lat, lon, self.opts.mission.kinematics.altitude)
        else:
            self._send_target_of(*self._lead_point(command))
        self._last_send = link.state.time_s

    def _lead_point(self, command: Command) -> tuple[float, float]:
        """Where the waypoint modes fly: ahead of the step's pose on the commanded heading.

        The next planned path point is one step (v dT) away, inside the acceptance radius of an
        autopilot (WP_RADIUS, NAV_ACC_RAD): it would count as reached at once and the vehicle
        would loiter around it. A point LEAD_STEPS steps (at least LEAD_MIN_M) out on the heading
        the plan reaches after its first step turns the vehicle onto that heading now.
        """
        assert self.last_position is not None
        k = self.opts.mission.kinematics
        lead = max(LEAD_STEPS * k.speed * k.step, LEAD_MIN_M)
        x, y = float(self.last_position[0]), float(self.last_position[1])
        return x + lead * math.cos(command.heading), y + lead * math.sin(command.heading)

    # -- one step --------------------------------------------------------------------------------
    def _pose(self, ahead: float = 0.0) -> tuple[float, float, float]:
        """The vehicle's pose `ahead` seconds from its latest telemetry, by eq. 2 under the command
        it is flying (grid mode: on the cell centre it is flying to, heading a multiple of 45 deg)."""
        s, kin = self.link.state, self.world.kinematics
        if kin.mode == "grid":  # grid UAVs sit on cell centres, headings on 45 deg
            g = self.world.grid
            eighth = math.pi / 4
            heading = round(s.heading / eighth) * eighth
            frac = max(ahead, 0.0) / self.dt
            x = s.x + frac * g.cell_size * round(math.cos(heading))
            y = s.y + frac * g.cell_size * round(math.sin(heading))
            col, row = round((x - g.x0) / g.cell_size), round((y - g.y0) / g.cell_size)
            return g.x0 + col * g.cell_size, g.y0 + row * g.cell_size, heading
        if ahead <= 0:
            return s.x, s.y, s.heading
        rate = self.last_command.heading_rate if self.last_command is not None and self.steering else 0.0
        x, y, h = arc_advance(s.x, s.y, s.heading, rate, kin.speed, ahead)
        return float(x), float(y), float(h)

    def _forget_departed(self) -> None:
        """A peer whose liveliness token vanished is forgotten at once, so its task goes back to the
        auction without waiting for the agent's peer timeout."""
        alive = self.mesh.alive_peers()
        for uav in self._seen_alive - alive:
            if uav not in self._departed:
                log.warning("uav %d: uav %d left the mesh; its task is free", self.opts.uav, uav)
            self.agent.forget(uav)  # every step: relayed states of it may still arrive
        self._departed = self._seen_alive - alive
        self._seen_alive |= alive

    def step(self, k: int, ahead: float = 0.0) -> Command:
        """Step k from the pose predicted `ahead` seconds on (the start of step k)."""
        self._forget_departed()
        x, y, heading = self._pose(ahead)
        seen = self.camera.take(round(k * self.dt * 1e6))
        own = self.last_position if self.last_position is not None else np.array([x, y])
        inbox = self.mesh.inbox(k, (float(own[0]), float(own[1])))
        command, outbox = self.agent.step(
            Observation(step=k, x=x, y=y, heading=heading, detections=seen), inbox
        )
        self.mesh.publish(k, outbox, position=(x, y))
        self.last_position = np.array([x, y])
        steered = self.steering and self._steerable()
        if steered:
            self._send(command)
        self.last_command = command
        self.steps_done += 1
        if self._log is not None:
            self._log.writerow(
                [
                    k,
                    f"{k * self.dt:.3f}",
                    f"{x:.4f}",
                    f"{y:.4f}",
                    f"{heading:.9f}",
                    command.task,
                    f"{float(self.agent.eta.mean()):.6f}",
                    len(self.agent.found),
                    int(steered),
                    f"{command.turn:.6f}",
                    f"{command.waypoint[0]:.3f}",
                    f"{command.waypoint[1]:.3f}",
                    len(self.agent.peers),
                ]
            )
            assert self._log_file is not None
            self._log_file.flush()
        return command

    # -- loops -----------------------------------------------------------------------------------
    def _check_link(self) -> bool:
        alive = self.link.link_alive(time.monotonic(), LINK_TIMEOUT_S)
        if alive != self.steering:
            self.steering = alive
            log.warning(
                "uav %d: vehicle link %s",
                self.opts.uav,
                "restored: steering again" if alive else "lost: not steering, state kept",
            )
        return alive

    def run(self, stop: threading.Event) -> int:
        seconds = warm_up(self.opts.mission)  # no compiling inside the first real steps
        log.info("uav %d: algorithm ready in %.1f s", self.opts.uav, seconds)
        log.info("uav %d: waiting for the vehicle at %s", self.opts.uav, self.opts.vehicle_url)
        self.link.wait_heartbeat(120.0, stop.is_set)
        log.info("uav %d: vehicle system %d is up", self.opts.uav, self.link.state.system)
        self.link.request_streams()
        if self.opts.lockstep:
            self.link.command_long(LOCKSTEP_COMMAND, 0)  # the simulator resends the current step's state
        while not stop.is_set() and not self.link.state.has_pose:
            self.link.poll(0.2)
        if self.opts.takeover:
            self._take_over(stop)
        budget = self.opts.steps if self.opts.steps is not None else self.opts.mission.steps
        if self.opts.lockstep:
            self._run_lockstep(stop, budget)
        else:
            self._run_realtime(stop, budget)
        return 0

    def _run_realtime(self, stop: threading.Event, budget: int) -> None:
        next_k: int | None = None
        last_beat = 0.0
        while not stop.is_set() and self.steps_done < budget:
            self.link.poll(0.02)
            now = time.monotonic()
            if now - last_beat >= 1.0:
                self.link.send_heartbeat()
                last_beat = now
            if not self._check_link() or not self.link.state.has_pose:
                continue
            t = self.link.state.time_s
            lead = LEAD * self.dt
            if next_k is None:
                next_k = math.ceil((t + lead) / self.dt - 1e-9)
            if t + lead + 1e-6 >= next_k * self.dt:
                k = math.floor((t + lead) / self.dt + 1e-6)
                self.step(k, ahead=k * self.dt - t)
                next_k = k + 1
            elif (
                self.opts.command_mode in STREAM_PERIOD_S
                and self.last_command is not None
                and self.steering
                and self._steerable()
                and t - self._last_send >= STREAM_PERIOD_S[self.opts.command_mode]
            ):
                self._send(self.last_command)

    def _run_lockstep(self, stop: threading.Event, budget: int) -> None:
        k = 0
        while not stop.is_set() and k < budget:
            while not stop.is_set() and self.link.state.time_s + 1e-6 < k * self.dt:
                self.link.poll(0.05)
                self._check_link()
            if stop.is_set():
                return
            self.camera.wait_until(round(k * self.dt * 1e6), PEER_WAIT_S)
            peers = self.mesh.alive_peers() - {self.opts.uav}
            if k > 0 and peers:
                missing = self.mesh.wait_for(k - 1, peers, PEER_WAIT_S)
                if missing:
                    log.warning("uav %d: step %d: no messages from %s", self.opts.uav, k, sorted(missing))
            self.step(k)
            self.link.command_long(LOCKSTEP_COMMAND, k + 1)
            self.link.send_heartbeat()
            k += 1

    def report(self) -> dict:
        """The companion's end-of-run record (what it learned, what it dropped)."""
        return {
            "uav": self.opts.uav,
            "steps": self.steps_done,
            "found_cells": sorted(int(c) for c in self.agent.found),
            "task": self.agent.task,
            "rejected_mavlink": self.link.rejected,
            "rejected_camera": self.camera.rejected,
            "mesh": asdict(self.mesh.stats),
        }

    def close(self) -> None:
        if self._log_file is not None:
            self._log_file.close()
        if self.opts.out is not None:
            (self.opts.out / f"uav{self.opts.uav}.json").write_text(
                json.dumps(self.report(), indent=2) + "\n"
            )


def camera_key_of(mission: Mission, uav: int) -> str:
    return camera_key(mission.mesh.key_prefix, mission.name, uav)
