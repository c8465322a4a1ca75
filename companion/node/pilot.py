"""The companion's step k: pose in, the agent's decision (eq. 2 onwards) out to the vehicle and mesh."""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from companion.contracts.frames import LocalFrame
from companion.contracts.mission import Mission
from companion.core.agent import Agent, Command, Observation
from companion.core.kinematics import arc_advance
from companion.core.search_area import region_hull
from companion.core.world import Stream, build_world, instance_rng
from companion.node.camera_feed import CameraFeed
from companion.node.departures import Departures
from companion.node.failsafe import FailsafeLoiter
from companion.node.faults import InjectedFaults
from companion.node.fence import fence_margin, fence_polygon
from companion.node.ground_station import GroundStationFeed
from companion.node.guidance import Guidance
from companion.node.journal import Header, Journal, Recovered, header_of
from companion.node.mesh import Mesh
from companion.node.records import RunLogs
from companion.node.takeover import steerable
from companion.node.target_watch import TargetWatch
from companion.node.tracking import Guard, PlanTracker, RegionGuard
from companion.node.vehicle_link import VehicleLink

log = logging.getLogger("companion")


@dataclass(frozen=True)
class CompanionOptions:
    """What one companion flies and how (`uavsearch companion`'s options)."""

    mission: Mission
    uav: int
    vehicle_url: str
    command_mode: str = "turn-rate"
    takeover: bool = False
    fence: bool | None = None  # upload the region plus margin as the autopilot's fence (default: takeover)
    failsafe: bool | None = None  # arm the autopilot's failsafe for our silence (default: takeover)
    lockstep: bool = False
    seed: int | None = None
    steps: int | None = None
    out: Path | None = None
    journal: Path | None = None  # the journal file (docs/reliability.md, "Restart without loss")
    run: str = ""  # the run identity (`keys.run_id`), kept in the journal
    gcs_reports: bool = True  # show the search to the ground station through the autopilot (`ground_station`)


class Pilot:
    """The per-step decision: the core's Agent run on the vehicle's pose.

    Each step sends the agent's command to the vehicle, its outbox to the mesh, and its state to the
    journal and the logs.
    """

    def __init__(self, opts: CompanionOptions, link: VehicleLink, mesh: Mesh, camera: CameraFeed) -> None:
        """The agent (restored from the journal when there is one), its guidance and its guards."""
        m = opts.mission
        self.opts, self.link, self.mesh, self.camera = opts, link, mesh, camera
        seed = m.seed if opts.seed is None else opts.seed
        self.world = build_world(m, seed, 0)
        self.agent = Agent(self.world, opts.uav)
        self.faults = InjectedFaults(m, opts.uav, instance_rng(seed, 2000 + opts.uav, Stream.RADIO))
        self.journal: Journal | None = None
        self.recovered: Recovered | None = None
        if opts.journal is not None:  # JournalError (a ValueError) for a journal of another mission
            self._restore(opts.journal, header_of(m, opts.uav, seed, opts.run))
        self.frame = LocalFrame(m.region.origin)
        self.targets = TargetWatch(opts.uav, self.frame, self.agent)  # candidates and confirmations
        self.dt = m.kinematics.step
        self.steps_done = 0
        self.last_position: np.ndarray | None = None
        self.steering = True  # the vehicle link is up (`watch.VehicleWatch` says when it is not)
        self.closing = False  # the mission is over: flying out the trajectory in force (`flyout`)
        self.last_command: Command | None = None
        self.guidance = Guidance(link, self.frame, m, opts.uav, opts.command_mode)
        k = m.kinematics
        self.tracker = PlanTracker(opts.uav, k.speed, k.step, bound_m=k.speed * k.step)
        margin = fence_margin(m)
        self.fence = fence_polygon(m, margin)
        self.guidance.fence = self.fence
        region = region_hull(m)
        # the guard acts half a step beyond the planning fence (plans may reach it; flights stray a
        # little), the autopilot's fence a whole step beyond (`preflight.upload_fence`)
        guard_fence = fence_polygon(m, margin + 0.5 * k.speed * k.step)
        self.guard = RegionGuard(opts.uav, region, guard_fence, depth=margin, step_length=k.speed * k.step)
        self.failsafe: FailsafeLoiter | None = None  # armed: kept on the trajectory in force's loiter
        self.departures = Departures()
        self.gcs = GroundStationFeed(link, self.frame, m, opts.uav) if opts.gcs_reports else None
        restarted = self.recovered is not None  # a restarted companion goes on with its logs
        self.logs = None if opts.out is None else RunLogs(opts.out, opts.uav, append=restarted)

    def _restore(self, path: Path, header: Header) -> None:
        """Open the journal; a journal with steps in it restores what the agent knew."""
        self.journal, self.recovered = Journal.open(path, header, self.agent)
        if self.recovered is not None:
            r = self.recovered
            log.warning(
                "uav %d: restarted from journal %s: step %d, %d targets known, mean uncertainty %.4f "
                "(%d torn bytes dropped)",
                self.opts.uav, path, r.step, len(self.agent.found), float(self.agent.eta.mean()),
                r.torn_bytes,
            )  # fmt: skip

    @property
    def journaled(self) -> int:
        """The last step this companion's journal holds (-1: none)."""
        return self.recovered.step if self.recovered is not None else -1

    def steerable(self) -> bool:
        """Whether the vehicle is in the mode the companion steers in."""
        return steerable(self.link, self.opts.command_mode)

    def pose(self, ahead: float = 0.0) -> tuple[float, float, float]:
        """The vehicle's pose `ahead` seconds from its latest telemetry, by eq. 2 (kinematics).

        Eq. 2 runs at the turn rate the vehicle is flying: the commanded one on the simulator's
        turn-rate command, the measured one (ATTITUDE) with an autopilot's guidance. Grid mode: on
        the cell centre it is flying to, heading a multiple of 45 deg.
        """
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
        if self.opts.command_mode != "turn-rate":  # autopilots turn at their own pace: as measured
            rate = s.turn_rate
        elif self.last_command is not None and self.steering:  # the simulator turns as told
            rate = self.last_command.heading_rate
        else:
            rate = 0.0
        ax, ay, ah = arc_advance(s.x, s.y, s.heading, rate, kin.speed, ahead)
        return float(ax), float(ay), float(ah)

    def _forget_departed(self, k: int) -> None:
        """Forget the peers whose liveliness token vanished (`departures.Departures`).

        Their tasks go back to the auction without waiting for the agent's peer timeout.
        """
        me, change = self.opts.uav, self.departures.update(k, self.mesh.alive_peers(), self.agent.peers)
        for uav in change.left:
            log.warning("uav %d: uav %d left the mesh; its task is free", me, uav)
        for uav in change.back:
            log.warning("uav %d: uav %d is flying again (heard through the others; no link to it)", me, uav)
        for uav in change.forget:
            self.agent.forget(uav)  # every step: relayed states of it may still arrive

    def step(self, k: int, ahead: float = 0.0) -> Command:
        """Step k from the pose predicted `ahead` seconds on (the start of step k)."""
        self._forget_departed(k)
        x, y, heading = self.pose(ahead)
        seen, frames = self.camera.take(round(k * self.dt * 1e6))
        own = self.last_position if self.last_position is not None else np.array([x, y])
        inbox = self.faults.filter(k, self.mesh.inbox(k, (float(own[0]), float(own[1]))))
        # whether the vehicle will fly this step's plan: the peers are told when it does not
        steered = self.steering and self.steerable() and self._guard(k, x, y)
        obs = Observation(
            step=k, x=x, y=y, heading=heading, detections=seen, steered=steered, closing=self.closing,
            looked=frames > 0,
        )  # fmt: skip
        command, outbox = self.agent.step(obs, inbox)
        if self.journal is not None:
            self.journal.append(self.agent)  # durable before any peer hears of this step
        events = self.targets.step(k, self.agent)
        self.mesh.publish(k, outbox, position=(x, y))
        self.last_position = np.array([x, y])
        self._fly(k, command, (x, y), steered)
        if self.gcs is not None:
            self.gcs.step(k, self.agent, steered)
        self.last_command = command
        self.steps_done += 1
        if self.logs is not None:
            pose = (x, y, heading)
            self.logs.step(k, self.dt, pose, command, self.agent, steered, self.link.state.up, self.closing)
            self.logs.targets(events)
        return command

    def _fly(self, k: int, command: Command, position: tuple[float, float], steered: bool) -> None:
        """Send step k's command to the vehicle and keep the failsafe loiter on the trajectory in force.

        The command goes to the vehicle (at `position`) when it flies the plan; else guidance pauses.
        """
        if steered:
            self.guidance.step(command, position)
            self.tracker.expect(k + 1, command.waypoint[0], command.waypoint[1], command.heading)
        else:
            self.guidance.paused()
            self.tracker.cancel()
        if self.failsafe is not None and steered:  # once the peers may have heard of this trajectory
            # in force; not steered, the loiter stays the one they keep clear of
            error = self.failsafe.follow(self.agent.commitments.inforce)
            if error:
                log.warning("uav %d: step %d: failsafe loiter not updated: %s", self.opts.uav, k, error)

    def _guard(self, k: int, x: float, y: float) -> bool:
        """The region guard's verdict on step k: True if the plan may be flown."""
        if self.guard.state is Guard.RELEASED:
            return False
        back_to = self.guard.check(k, x, y)
        if back_to is not None:
            self.guidance.go_to(*back_to)
        return self.guard.state is Guard.INSIDE

    def measure(self) -> None:
        """Plan versus flight, once the vehicle's telemetry reaches the planned step's time."""
        s = self.link.state
        error = self.tracker.measure(s.time_s, s.x, s.y, s.heading)
        if error is not None and self.logs is not None:
            self.logs.plan(error)
