"""The simulator process: every vehicle of a mission, its endpoint, the clock and the camera.

One thread, one selector loop. Each turn of the loop runs the physics ticks the clock allows
(vectorised over the fleet), sends the telemetry that fell due in simulated time, sends the
wall-clock HEARTBEATs, then waits for datagrams until the next tick is due.
"""

from __future__ import annotations

import contextlib
import math
import selectors
import socket
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from companion.contracts.frames import LocalFrame
from companion.contracts.keys import for_mission, mavlink_secrets
from companion.contracts.mission import Mission
from companion.core.kinematics import Kinematics
from sim_vehicles import camera as cam
from sim_vehicles.approach import ApproachRecorder
from sim_vehicles.clock import LockstepClock, RealTimeClock
from sim_vehicles.dynamics.flight import BankedFlight, Demand, Flight, GridFlight, KinematicFlight
from sim_vehicles.hosted_vehicle import HostedVehicle
from sim_vehicles.mavlink_endpoint import InputStats, MavlinkEndpoint
from sim_vehicles.modes import FLAVOURS
from sim_vehicles.protocols.params import ParamStore, param_specs
from sim_vehicles.resume import load_state, save_state
from sim_vehicles.vehicle import Vehicle

from pymavlink.dialects.v20 import ardupilotmega as mavlink  # isort: skip

M = mavlink
MAX_TICKS_PER_LOOP = 500  # keep serving sockets when far behind
# A GCS failsafe's ground station silent for longer than this (simulated seconds: twice the
# companion's HEARTBEAT period in vehicle time) has not been scheduled: real time until it speaks
GCS_QUIET_S = 1.0


@dataclass(frozen=True)
class HostOptions:
    """How the simulator runs: its clock, flavour, seed, camera and the files it writes."""

    speedup: float = 1.0
    lockstep: bool = False
    flavour: str | None = None  # None: the mission's
    seed: int | None = None  # None: the mission's
    camera: bool = True
    zenoh_listen: tuple[str, ...] = ("tcp/127.0.0.1:0",)
    zenoh_connect: tuple[str, ...] | None = None  # None: the mission's seed endpoint / router
    truth: Path | None = None
    approach: Path | None = None  # the physics-rate closest approaches (sim_vehicles.approach)
    host: str | None = None  # None: the mission's sim.host
    state: Path | None = None  # save the state every step; resume from it if it exists (resume.py)


@dataclass
class RunStats:
    """What a run did: simulated, wall and CPU time, camera frames, time given up, bad input."""

    sim_time: float = 0.0
    wall_time: float = 0.0
    cpu_time: float = 0.0
    frames_published: int = 0
    slipped: float = 0.0  # simulated seconds given up to a busy machine (RealTimeClock.slip)
    paced: float = 0.0  # wall seconds run at real time for a silent ground station (RealTimeClock.pace)
    input: InputStats = field(default_factory=InputStats)

class Host:
    """All vehicles of a mission in one process."""

    def __init__(self, mission: Mission, options: HostOptions) -> None:
        self.mission, self.options = mission, options
        self.frame = LocalFrame(mission.region.origin)
        self.unix_epoch_usec = int(time.time() * 1e6)
        k = mission.kinematics
        self.substeps = max(1, math.ceil(k.step * mission.sim.physics_hz - 1e-9))
        self.tick_dt = k.step / self.substeps
        self.tick = 0
        self.flight = self._build_flight()
        flavour = FLAVOURS[options.flavour or mission.sim.flavour]
        specs = param_specs(mission)
        self.clock: RealTimeClock | LockstepClock
        if options.lockstep:
            self.clock = LockstepClock(self.tick_dt, self.substeps, mission.n_uavs)
        else:
            self.clock = RealTimeClock(self.tick_dt, options.speedup, time.monotonic())
        self.pending_snapshots: set[int] = set()
        self.snapshot_step = 0
        self.seed = mission.seed if options.seed is None else options.seed
        self.grid, self.targets = cam.draw_truth(mission, self.seed)
        self.hosted: list[HostedVehicle] = []
        self.selector = selectors.DefaultSelector()
        self.wakeup_r, self.wakeup_w = socket.socketpair()
        self.wakeup_r.setblocking(False)
        self.wakeup_w.setblocking(False)
        self.selector.register(self.wakeup_r, selectors.EVENT_READ, None)
        self.bus: cam.CameraBus | None = None
        self.resumed = False
        self._saved_tick = -1
        self.stopping = False
        self.stats = RunStats()
        self.approach = (
            ApproachRecorder(
                options.approach, mission.n_uavs, k.step, 3 * mission.comms.safety, mission.comms.safety
            )
            if options.approach is not None
            else None
        )
        try:
            bind = options.host or mission.sim.host
            secrets = mavlink_secrets(mission)
            for i, v in enumerate(mission.vehicles):
                vehicle = Vehicle(
                    i,
                    flavour,
                    ParamStore(specs, flavour.name, k.mode == "grid"),
                    (v.x, v.y),
                    mission.altitude_of(i),
                    k.step,
                )
                secret = secrets[i] if secrets else None
                endpoint = MavlinkEndpoint(bind, mission.vehicle_port(i), i + 1, secret)
                hv = HostedVehicle(self, i, vehicle, endpoint)
                self.hosted.append(hv)
                self.selector.register(endpoint, selectors.EVENT_READ, hv)
            if options.truth is not None:
                record = cam.truth_record(mission, self.seed, self.grid, self.targets, self.frame)
                cam.write_truth(options.truth, record)
            self.camera = cam.Camera(mission, self.grid, self.targets, self.seed, self.frame)
            self.next_camera = 0.0
            if options.state is not None and options.state.exists():
                load_state(self, options.state)
                self.resumed = True
                self._saved_tick = self.tick
            if options.camera:
                connect = options.zenoh_connect
                if connect is None:
                    mesh = mission.mesh
                    connect = (mesh.seed_endpoint if mesh.mode == "peer" else mesh.router,)
                keys = for_mission(mission, "camera")
                self.bus = cam.CameraBus(mission, list(options.zenoh_listen), list(connect), keys)
        except BaseException:
            self.close()
            raise

    def _build_flight(self) -> Flight:
        m = self.mission
        poses = np.array([(v.x, v.y, math.radians(v.heading_deg)) for v in m.vehicles], dtype=float)
        alt = np.array([m.altitude_of(i) for i in range(m.n_uavs)])
        k = m.kinematics
        if k.mode == "grid":
            kin = Kinematics(k.mode, k.speed, k.step, math.radians(k.turn_limit_deg), m.region.cell_size)
            return GridFlight(poses, alt, k.step, self.substeps, kin)
        model = BankedFlight if m.sim.dynamics == "arduplane" else KinematicFlight
        return model(poses, alt, k.step, self.substeps)

    @property
    def t(self) -> float:
        """Simulated time (s)."""
        return self.tick * self.tick_dt

    @property
    def signed(self) -> bool:
        """True when every vehicle requires signed MAVLink (the mission's [security] keys)."""
        return all(hv.endpoint.signing for hv in self.hosted)

    @property
    def endpoints(self) -> list[tuple[int, str, int]]:
        """(vehicle index, host, port) of every endpoint."""
        return [(hv.index, *hv.endpoint.sock.getsockname()) for hv in self.hosted]

    def stop(self) -> None:
        """Ask the loop to end (safe from a signal handler)."""
        self.stopping = True
        with contextlib.suppress(OSError):
            self.wakeup_w.send(b"\0")

    # ---- the loop -----------------------------------------------------------------------
    def run(self) -> RunStats:
        wall0, cpu0 = time.monotonic(), time.process_time()
        if isinstance(self.clock, RealTimeClock):
            self.clock.wall_start = wall0
        next_second = wall0
        while not self.stopping:
            now = time.monotonic()
            if isinstance(self.clock, RealTimeClock):
                self.clock.slip(now, self.tick)
                self.clock.pace(now, self.tick, self._awaiting_gcs())
            target = self.clock.target(now)
            budget = MAX_TICKS_PER_LOOP
            while self.tick < target and budget:
                self._tick()
                budget -= 1
            self._save_state()
            if isinstance(self.clock, LockstepClock) and self.tick == target:
                if self.clock.step != self.snapshot_step:
                    self.snapshot_step = self.clock.step
                    self.pending_snapshots.update(range(len(self.hosted)))
                for i in sorted(self.pending_snapshots):
                    self._snapshot(self.hosted[i])
                self.pending_snapshots.clear()
            if now >= next_second:
                self._every_second(now)
                next_second = max(next_second + 1.0, now)
            behind = self.tick < target
            self._serve(0.0 if behind else max(0.0, min(self.clock.sleep(now, self.tick), next_second - now)))
        self.stats.sim_time = self.t
        if isinstance(self.clock, RealTimeClock):
            self.stats.slipped = self.clock.slipped
            self.stats.paced = self.clock.paced_until(time.monotonic())
        self.stats.wall_time = time.monotonic() - wall0
        self.stats.cpu_time = time.process_time() - cpu0
        for hv in self.hosted:
            self.stats.input.add(hv.stats)
        return self.stats

    def _awaiting_gcs(self) -> bool:
        """Whether a vehicle's GCS failsafe counts a silence longer than `GCS_QUIET_S`."""
        t = self.t
        return any(hv.vehicle.awaits_gcs(t, GCS_QUIET_S) for hv in self.hosted)

    def _save_state(self) -> None:
        """At each step boundary, the state a restarted simulator resumes from (`--state`)."""
        path = self.options.state
        if path is not None and self.tick % self.substeps == 0 and self.tick != self._saved_tick:
            save_state(self, path)
            self._saved_tick = self.tick

    def _serve(self, timeout: float) -> None:
        for key, _ in self.selector.select(timeout):
            hv = key.data
            if hv is None:
                with contextlib.suppress(OSError):
                    self.wakeup_r.recv(4096)
                continue
            for msg, addr in hv.endpoint.receive(time.monotonic()):
                hv.route(msg, addr)
                hv.handle(msg, addr)
            hv.flush()

    def _every_second(self, now: float) -> None:
        for hv in self.hosted:
            hv.broadcast(hv.build(M.MAVLINK_MSG_ID_HEARTBEAT))
            hv.endpoint.expire(now)
            hv.report_bad_input(now)

    def _tick(self) -> None:
        fl, hosted = self.flight, self.hosted
        if fl.needs_demand():
            t = self.t
            d = self._demand = Demand.empty(len(hosted))
            for i, hv in enumerate(hosted):
                v = hv.vehicle
                mode = v.mode
                turn = v.steer(t, float(fl.x[i]), float(fl.y[i]), float(fl.heading[i]))
                if v.mode != mode:  # a failsafe or the fence changed it: say so at once
                    hv.broadcast(hv.build(M.MAVLINK_MSG_ID_HEARTBEAT))
                d.by_bank[i], d.bank[i] = turn.bank is not None, turn.bank or 0.0
                d.rate[i], d.bank_limit[i] = turn.rate, turn.limit
                d.moving[i], d.speed[i], d.turn_limit[i], d.roll_limit[i] = (
                    v.armed, v.speed, v.turn_limit, v.roll_limit
                )
                fl.alt_target[i] = v.alt_target
                if v.texts or v.reached:
                    hv.flush()
        fl.tick(self._demand)
        self.tick += 1
        t = self.t
        if self.approach is not None:
            self.approach.update(t, fl.x, fl.y, fl.alt)
        for hv in hosted:
            if t >= hv.streams.next_any:
                for msgid in hv.streams.due(t):
                    hv.broadcast(hv.build(msgid))
        if self.bus is not None and isinstance(self.clock, RealTimeClock) and t >= self.next_camera - 1e-9:
            self.next_camera += 1.0 / self.mission.sim.camera_hz
            for hv in hosted:
                self._publish_frame(hv)

    def _snapshot(self, hv: HostedVehicle) -> None:
        """Full-precision state of one vehicle at the current step (lockstep)."""
        if self.bus is not None:
            self._publish_frame(hv)
        for msgid in (
            M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT,
            M.MAVLINK_MSG_ID_ATTITUDE,
            M.MAVLINK_MSG_ID_LOCAL_POSITION_NED,
        ):
            hv.broadcast(hv.build(msgid))

    def _publish_frame(self, hv: HostedVehicle) -> None:
        assert self.bus is not None
        p = hv.pose()
        frame = self.camera.frame(hv.index, round(self.t * 1e6), (p.x, p.y), (p.lat, p.lon, p.alt), p.heading)
        self.bus.publish(frame)
        self.stats.frames_published += 1

    def close(self) -> None:
        if self.bus is not None:
            self.bus.close()
            self.bus = None
        if self.approach is not None:
            self.approach.close()
            self.approach = None
        for hv in self.hosted:
            hv.endpoint.close()
        self.selector.close()
        self.wakeup_r.close()
        self.wakeup_w.close()
