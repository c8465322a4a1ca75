"""The companion process: one per UAV, driving the core's Agent with real I/O.

Every sampling step k (vehicle time k * dT) it reads its vehicle's pose over MAVLink, takes the
camera's detections, takes the peers' step k-1 messages from the mesh, calls `Agent.step`, sends
the command to the vehicle in the chosen command mode (only while the vehicle is in its guided
mode) and publishes the outbox. The clock is the vehicle's: a sped-up simulator just works.

On connecting it reads the autopilot's airframe parameters, warns when the mission cannot be flown
and refuses command modes the autopilot does not fly (`airframe`); with `--takeover` it puts the
vehicle in guided flight (`takeover`), uploads the region plus its margin as the autopilot's fence
(`fence`) with the autopilot's return altitude set to the UAV's layer (`return_altitude`) and arms
the autopilot's failsafe for its own silence (`failsafe`). Every step it
measures how far the vehicle is from where the plan put it and guards the region (`tracking`).

In lockstep the bundled simulator advances only when every companion has reported that its step
is done (MAV_CMD_USER_1, see docs/simulator.md), and each step waits for the pose, the camera frame
and the peers' messages of that step, so a distributed run reproduces the batch engine's.

With a journal (`journal`) every step is written to disk before its bundle goes out; a companion
started again on the same journal (after a kill, say) restores what its agent knew, joins the mesh
only once it can step, and goes on from its vehicle's current step with its journaled trajectory
in force re-anchored at the vehicle's pose (docs/reliability.md, "Restart without loss").
"""

from __future__ import annotations

import csv
import json
import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from companion.core.agent import Agent, Command, Observation
from companion.core.geometry import ConvexPolygon
from companion.core.kinematics import arc_advance
from companion.core.warm import warm_up
from companion.core.world import Stream, build_world, instance_rng
from companion.mission import Mission
from companion.node.airframe import SIMULATOR_PARAM, Airframe, check_mission, refusal
from companion.node.camera_feed import CameraFeed
from companion.node.departures import Departures
from companion.node.detections import camera_key
from companion.node.failsafe import FailsafeLoiter, arm_failsafe, fired_by_our_silence, hand_over
from companion.node.faults import InjectedFaults
from companion.node.fence import fence_margin, fence_polygon, upload_fence
from companion.node.frames import LocalFrame
from companion.node.guidance import Guidance
from companion.node.journal import Journal, Recovered, header_of
from companion.node.mesh import Mesh
from companion.node.return_altitude import set_return_altitude
from companion.node.takeover import guided_mode, steerable, take_over
from companion.node.tracking import Guard, PlanError, PlanTracker, RegionGuard
from companion.node.vehicle_link import ARDUPILOT_AUTO, PX4_HOLD, VEHICLE_WAIT_S, VehicleLink

log = logging.getLogger("companion")

FLY_OUT_SLACK_S = 10.0  # wall seconds the fly-out may take beyond twice its vehicle time
LOCKSTEP_COMMAND = 31010  # MAV_CMD_USER_1: "lockstep: ready for step param1"
# In real time a step is planned LEAD of a step before it starts, from the pose predicted for its
# start, so that the command is in place when the autopilot begins the step (no one-step lag).
LEAD = 0.25
LINK_TIMEOUT_S = 3.0  # wall seconds without HEARTBEAT before the link counts as lost
RETAKE_PERIOD_S = 1.0  # wall seconds between requests for GUIDED after our own failsafe fired
PX4_OFFBOARD_LOSS = "COM_OF_LOSS_T"  # PX4: seconds without setpoints before the OFFBOARD failsafe
PEER_WAIT_S = 30.0  # lockstep: how long to wait for a live peer's messages before going on
SIMULATOR_PARAM_WAIT_S = 3.0  # the airframe's parameters have answered by then: others need no longer
LOG_COLUMNS = [
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
    "up",
    "closing",
]
PLAN_COLUMNS = [
    "step",
    "planned_x",
    "planned_y",
    "planned_heading",
    "x",
    "y",
    "heading",
    "error_m",
    "error_deg",
]


def _open_log(path: Path, columns: list[str], append: bool) -> tuple[TextIO, Any]:
    """A CSV step log: new with its header row, or continued (after a line a kill cut short)."""
    if append and path.exists() and path.stat().st_size > 0:
        with path.open("rb") as f:
            f.seek(-1, 2)
            torn = f.read(1) != b"\n"
        f = path.open("a", newline="")
        if torn:
            f.write("\n")
        return f, csv.writer(f)
    f = path.open("w", newline="")
    writer = csv.writer(f)
    writer.writerow(columns)
    return f, writer


class Refused(RuntimeError):
    """The autopilot cannot fly the mission in the chosen command mode (the message says why)."""


@dataclass(frozen=True)
class CompanionOptions:
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
        self.faults = InjectedFaults(m, opts.uav, instance_rng(seed, 2000 + opts.uav, Stream.RADIO))
        self.journal: Journal | None = None
        self.recovered: Recovered | None = None
        if opts.journal is not None:  # JournalError (a ValueError) for a journal of another mission
            header = header_of(m, opts.uav, seed, opts.run)
            self.journal, self.recovered = Journal.open(opts.journal, header, self.agent)
            if self.recovered is not None:
                r = self.recovered
                log.warning(
                    "uav %d: restarted from journal %s: step %d, %d targets known, mean uncertainty %.4f "
                    "(%d torn bytes dropped)",
                    opts.uav, opts.journal, r.step, len(self.agent.found), float(self.agent.eta.mean()),
                    r.torn_bytes,
                )  # fmt: skip
        self.frame = LocalFrame(m.region.origin)
        self.dt = m.kinematics.step
        self.steps_done = 0
        self.last_position: np.ndarray | None = None
        self.steering = True
        self.last_command: Command | None = None
        self.guidance = Guidance(link, self.frame, m, opts.uav, opts.command_mode)
        k = m.kinematics
        self.tracker = PlanTracker(opts.uav, k.speed, k.step, bound_m=k.speed * k.step)
        margin = fence_margin(m)
        self.fence = fence_polygon(m, margin)
        self.guidance.fence = self.fence
        region = ConvexPolygon.from_vertices(m.region.polygon)
        # the guard acts half a step beyond the planning fence (plans may reach it; flights stray a
        # little), the autopilot's fence a whole step beyond (`_upload_fence`)
        guard_fence = fence_polygon(m, margin + 0.5 * k.speed * k.step)
        self.guard = RegionGuard(opts.uav, region, guard_fence, depth=margin, step_length=k.speed * k.step)
        self.airframe_warnings: list[str] = []
        self.fence_uploaded = False
        self.failsafe: FailsafeLoiter | None = None  # armed: kept on the trajectory in force's loiter
        self._was_steerable = False
        self._texts_steering = 0  # the vehicle's STATUSTEXTs counted while we last steered it
        self._retake_asked: float | None = None  # our failsafe fired: when GUIDED was last asked for
        self._offboard_loss_s: float | None = None  # PX4 OFFBOARD: its COM_OF_LOSS_T (vehicle seconds)
        self._silent_at = -math.inf  # PX4 OFFBOARD: vehicle time our setpoints last paused that long
        self.departures = Departures()
        self._resync = False  # lockstep: the link was lost, the vehicle may have gone on without us
        self._k: int | None = None  # the next step to fly (None: not started)
        self._joined = 0  # lockstep: the step this companion joined the mesh at
        self.closing = False  # the mission is over: flying out the trajectory in force (`_close`)
        self._log_file = self._plan_file = None
        self._log = self._plan_log = None
        if opts.out is not None:
            opts.out.mkdir(parents=True, exist_ok=True)
            append = self.recovered is not None  # a restarted companion goes on with its logs
            self._log_file, self._log = _open_log(opts.out / f"uav{opts.uav}.csv", LOG_COLUMNS, append)
            self._plan_file, self._plan_log = _open_log(
                opts.out / f"uav{opts.uav}_plan.csv", PLAN_COLUMNS, append
            )

    # -- vehicle ---------------------------------------------------------------------------------
    def _steerable(self) -> bool:
        return steerable(self.link, self.opts.command_mode)

    def _keep_streaming(self) -> None:
        """Repeat the streamed guidance when due, also while a request waits for its reply (PX4
        leaves OFFBOARD when its setpoints stop for COM_OF_LOSS_T), and while it asks PX4 for
        OFFBOARD back (PX4 accepts it only while setpoints stream)."""
        s = self.link.state
        loss = self._offboard_loss_s
        silent = s.time_s - self.guidance.last_send
        if loss is not None and self._was_steerable and self.guidance.due(s.time_s) and silent >= loss:
            self._silent_at = s.time_s  # in OFFBOARD, our setpoints paused: PX4's failsafe may have fired
        if (
            self.steering
            and self.guard.state is not Guard.RELEASED
            and (self._steerable() or (s.px4 and self._retake_asked is not None))
            and self.guidance.due(s.time_s)
        ):
            self.guidance.repeat()  # the plan's command, or the way back inside

    def _check_airframe(self) -> None:
        """Read the airframe's parameters, warn about what the mission asks beyond them, refuse
        what the autopilot cannot fly."""
        flavour = "px4" if self.link.state.px4 else "ardupilot"
        values = self.link.read_params(Airframe.names(flavour))
        values |= self.link.read_params([SIMULATOR_PARAM], timeout=SIMULATOR_PARAM_WAIT_S)
        airframe = Airframe.from_params(flavour, values)
        problem = refusal(self.opts.mission, airframe, self.opts.command_mode)
        if problem:
            raise Refused(f"uav {self.opts.uav}: {problem}")
        self.airframe_warnings = check_mission(self.opts.mission, airframe)
        for warning in self.airframe_warnings:
            log.warning("uav %d: mission vs airframe: %s", self.opts.uav, warning)
        cruise = airframe.get("cruise")
        k = self.opts.mission.kinematics
        self.guidance.set_speed = (
            k.mode == "continuous" and cruise is not None and abs(cruise - k.speed) > 0.1
        )

    def _upload_fence(self) -> None:
        """The autopilot's fence: the planning fence (region plus margin) plus one step of slack for
        the vehicle's tracking error; the companion's own guard acts at the planning fence."""
        m = self.opts.mission
        margin = fence_margin(m) + m.kinematics.speed * m.kinematics.step
        error = upload_fence(self.link, self.frame, fence_polygon(m, margin))
        if error:
            log.warning("uav %d: fence not set: %s", self.opts.uav, error)
        else:
            self.fence_uploaded = True
            log.info(
                "uav %d: fence enabled: the region plus %.0f m (%d vertices)",
                self.opts.uav,
                margin,
                len(self.fence.vertices),
            )

    def _set_return_altitude(self) -> None:
        """The autopilot's return (the fence's breach action) at the UAV's layer (`return_altitude`)."""
        altitude = self.opts.mission.altitude_of(self.opts.uav)
        error = set_return_altitude(self.link, altitude)
        if error:
            log.warning("uav %d: return altitude not set: %s", self.opts.uav, error)
        else:
            log.info("uav %d: return (RTL) altitude set to its layer, %.0f m", self.opts.uav, altitude)

    def _arm_failsafe(self) -> None:
        if self.link.state.px4:
            if self.opts.command_mode == "position-target":
                self._offboard_loss_s = self.link.read_params([PX4_OFFBOARD_LOSS]).get(PX4_OFFBOARD_LOSS)
            if self._offboard_loss_s is None:
                log.info("uav %d: failsafe: PX4's own failsafes apply", self.opts.uav)
            else:
                log.info(
                    "uav %d: failsafe: PX4's own offboard-loss failsafe applies after %s = %g s; OFFBOARD "
                    "taken back when our setpoints paused that long",
                    self.opts.uav,
                    PX4_OFFBOARD_LOSS,
                    self._offboard_loss_s,
                )
            return
        m = self.opts.mission
        failsafe = FailsafeLoiter(self.link, self.world, self.opts.uav, self.frame)
        error = arm_failsafe(failsafe, self.agent.commitments.inforce)
        if error:
            log.warning("uav %d: failsafe not set: %s", self.opts.uav, error)
            return
        self.failsafe = failsafe
        log.info(
            "uav %d: failsafe armed: %g s without our HEARTBEAT, the aircraft circles the loiter of its "
            "trajectory in force",
            self.opts.uav,
            m.failsafe_seconds,
        )

    # -- one step --------------------------------------------------------------------------------
    def _pose(self, ahead: float = 0.0) -> tuple[float, float, float]:
        """The vehicle's pose `ahead` seconds from its latest telemetry, by eq. 2 at the turn rate it
        is flying: the commanded one on the simulator's turn-rate command, the measured one
        (ATTITUDE) with an autopilot's guidance; grid mode: on the cell centre it is flying to,
        heading a multiple of 45 deg."""
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
        x, y, h = arc_advance(s.x, s.y, s.heading, rate, kin.speed, ahead)
        return float(x), float(y), float(h)

    def _forget_departed(self, k: int) -> None:
        """Forget the peers whose liveliness token vanished (`departures.Departures`), so that their
        tasks go back to the auction without waiting for the agent's peer timeout."""
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
        x, y, heading = self._pose(ahead)
        seen = self.camera.take(round(k * self.dt * 1e6))
        own = self.last_position if self.last_position is not None else np.array([x, y])
        inbox = self.faults.filter(k, self.mesh.inbox(k, (float(own[0]), float(own[1]))))
        # whether the vehicle will fly this step's plan: the peers are told when it does not
        steered = self.steering and self._steerable() and self._guard(k, x, y)
        command, outbox = self.agent.step(
            Observation(
                step=k, x=x, y=y, heading=heading, detections=seen, steered=steered, closing=self.closing
            ),
            inbox,
        )
        if self.journal is not None:
            self.journal.append(self.agent)  # durable before any peer hears of this step
        self.mesh.publish(k, outbox, position=(x, y))
        self.last_position = np.array([x, y])
        if steered:
            self.guidance.step(command, (x, y))
            self.tracker.expect(k + 1, command.waypoint[0], command.waypoint[1], command.heading)
        else:
            self.guidance.paused()
            self.tracker.cancel()
        if self.failsafe is not None and steered:  # once the peers may have heard of this trajectory
            # in force; not steered, the loiter stays the one they keep clear of
            error = self.failsafe.follow(self.agent.commitments.inforce)
            if error:
                log.warning("uav %d: step %d: failsafe loiter not updated: %s", self.opts.uav, k, error)
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
                    f"{self.link.state.up:.2f}",
                    int(self.closing),
                ]
            )
            assert self._log_file is not None
            self._log_file.flush()
        return command

    def _guard(self, k: int, x: float, y: float) -> bool:
        """The region guard's verdict on step k: True if the plan may be flown."""
        if self.guard.state is Guard.RELEASED:
            return False
        back_to = self.guard.check(k, x, y)
        if back_to is not None:
            self.guidance.go_to(*back_to)
        return self.guard.state is Guard.INSIDE

    def _measure(self) -> None:
        """Plan versus flight, once the vehicle's telemetry reaches the planned step's time."""
        s = self.link.state
        error = self.tracker.measure(s.time_s, s.x, s.y, s.heading)
        if error is not None:
            self._log_plan(error)

    def _log_plan(self, e: PlanError) -> None:
        if self._plan_log is None:
            return
        self._plan_log.writerow(
            [
                e.step,
                *(f"{v:.3f}" for v in e.planned[:2]),
                f"{e.planned[2]:.6f}",
                *(f"{v:.3f}" for v in e.flown[:2]),
                f"{e.flown[2]:.6f}",
                f"{e.position_m:.3f}",
                f"{e.heading_deg:.3f}",
            ]
        )
        assert self._plan_file is not None
        self._plan_file.flush()

    # -- loops -----------------------------------------------------------------------------------
    def _check_mode(self) -> None:
        """Say when the vehicle leaves the mode the companion steers in (a failsafe, a pilot); take it
        back into GUIDED if it left for the GCS failsafe this companion armed (it was stalled)."""
        steerable, s = self._steerable(), self.link.state
        if self._was_steerable and not steerable:
            log.warning(
                "uav %d: the vehicle left its guided mode (now custom mode %d%s): not steering",
                self.opts.uav,
                s.custom_mode,
                f"; it said '{s.texts[-1]}'" if s.texts else "",
            )
        self._was_steerable = steerable
        if steerable:
            if self._retake_asked is not None:
                log.info("uav %d: back in GUIDED: steering again", self.opts.uav)
            self._texts_steering, self._retake_asked = s.text_count, None
            return
        failsafe_mode = PX4_HOLD if s.px4 else ARDUPILOT_AUTO
        if self._retake_asked is None:
            if not self._our_failsafe_fired() or self.closing:
                return
            what = "offboard-loss" if s.px4 else "GCS"
            log.warning(
                "uav %d: our own %s failsafe fired (we were stalled): taking it back", self.opts.uav, what
            )
            self._retake_asked = -math.inf
        if s.custom_mode != failsafe_mode:  # someone else chose a mode since: theirs
            log.warning("uav %d: mode %d chosen since: not taking it back", self.opts.uav, s.custom_mode)
            self._texts_steering, self._retake_asked = s.text_count, None
        elif time.monotonic() - self._retake_asked >= RETAKE_PERIOD_S:
            self.link.set_mode(guided_mode(self.link, self.opts.command_mode))
            self._retake_asked = time.monotonic()

    def _our_failsafe_fired(self) -> bool:
        """Whether the vehicle left its guided mode for the failsafe this companion's own silence set
        off: ArduPilot's GCS failsafe it armed (ArduPlane said so), or PX4's offboard-loss failsafe
        (Hold, found at most COM_OF_LOSS_T of vehicle time after our setpoints, streamed in OFFBOARD,
        had paused that long: a Hold a pilot chose while they flowed is not ours); never once the
        region guard has given the aircraft up to the autopilot's fence."""
        s = self.link.state
        if self.guard.state is Guard.RELEASED:  # it gave the aircraft up for good
            return False
        if s.px4:
            loss = self._offboard_loss_s
            return loss is not None and s.custom_mode == PX4_HOLD and s.time_s - self._silent_at <= loss
        return self.failsafe is not None and fired_by_our_silence(self.link, self._texts_steering)

    def _check_link(self) -> bool:
        """Whether the vehicle link is up. A companion whose link is lost cannot steer: it leaves the
        mesh (its peers take its UAV as gone, flying its last commitments and then its failsafe)
        and joins again when the link is back (in lockstep, once it has caught up: `_catch_up`)."""
        self._check_mode()
        alive = self.link.link_alive(time.monotonic(), LINK_TIMEOUT_S)
        if alive != self.steering:
            self.steering = alive
            log.warning(
                "uav %d: vehicle link %s",
                self.opts.uav,
                "restored: steering again" if alive else "lost: not steering, state kept, left the mesh",
            )
            if not alive:
                self.mesh.leave()
                self._resync = True
            elif not self.opts.lockstep:
                self.mesh.join()
        return alive

    def run(self, stop: threading.Event, abort: threading.Event | None = None) -> int:
        """Fly the mission until its step budget is spent or `stop`, then close it (`_close`) unless
        `abort` (a second signal) cuts that short."""
        abort = abort if abort is not None else threading.Event()
        seconds = warm_up(self.opts.mission)  # no compiling inside the first real steps
        log.info("uav %d: algorithm ready in %.1f s", self.opts.uav, seconds)
        log.info("uav %d: waiting for the vehicle at %s", self.opts.uav, self.opts.vehicle_url)
        if not self.link.wait_heartbeat(VEHICLE_WAIT_S, stop.is_set):
            return 0  # stopped before the vehicle answered: nothing flown, nothing to close
        log.info("uav %d: vehicle system %d is up", self.opts.uav, self.link.state.system)
        self.link.request_streams()
        self.link.on_poll = self._keep_streaming  # from the take-over on, whatever waits
        self._check_airframe()
        if self.opts.lockstep:
            self.link.command_long(LOCKSTEP_COMMAND, 0)  # the simulator resends the current step's state
        while not stop.is_set() and not self.link.state.has_pose:
            self.link.poll(0.2)
        if self.opts.takeover:
            take_over(self.link, self.guidance, self.opts.uav, stop)
        if (self.opts.takeover if self.opts.fence is None else self.opts.fence) and not stop.is_set():
            self._upload_fence()
            self._set_return_altitude()
        if (self.opts.takeover if self.opts.failsafe is None else self.opts.failsafe) and not stop.is_set():
            self._arm_failsafe()
        budget = self.opts.steps if self.opts.steps is not None else self.opts.mission.steps
        if self.opts.lockstep:
            self._run_lockstep(stop.is_set, budget)
        else:
            self._run_realtime(stop.is_set, budget)
        if self.steps_done and not abort.is_set():
            self._close(stopped=stop.is_set(), abort=abort)
        return 0

    def _close(self, stopped: bool, abort: threading.Event) -> None:
        """The mission is over: fly out the trajectory in force (horizon + 1 steps without a new
        proposal, so that every turn it planned is flown and it is in its loiter), then hand the
        aircraft to that loiter (`hand_over`). Every peer's trajectory in force keeps clear of it,
        and theirs of each other's, whenever each of them stops. In lockstep every companion takes
        those steps, steering or not (the simulator advances when all are ready), and a swarm stopped
        by a signal stops its simulated time with it: there is nothing to fly out."""
        lockstep = self.opts.lockstep
        if (stopped and lockstep) or (not lockstep and not (self.steering and self._steerable())):
            return
        self.closing = True
        steps = self.opts.mission.algorithm.horizon + 1
        log.info("uav %d: mission over: flying out the trajectory in force (%d steps)", self.opts.uav, steps)
        deadline = time.monotonic() + FLY_OUT_SLACK_S + 2 * steps * self.dt

        def cut() -> bool:  # a second signal, a vehicle whose clock stands still, a lost link
            return abort.is_set() or time.monotonic() > deadline or (not lockstep and not self.steering)

        if lockstep:
            self._run_lockstep(cut, (self._k or 0) + steps)
        else:
            self._run_realtime(cut, self.steps_done + steps)
        if cut():
            log.warning("uav %d: fly-out cut short: no hand-over", self.opts.uav)
            return
        if not (self.steering and self._steerable()):
            log.warning("uav %d: not steering at the mission's end: no hand-over", self.opts.uav)
            return
        if not self.agent.commitments.loitering():
            log.warning("uav %d: the trajectory in force is not in its loiter yet", self.opts.uav)
        if self.failsafe is None:
            log.warning(
                "uav %d: no failsafe loiter armed: the aircraft flies its last guidance", self.opts.uav
            )
            return
        error = hand_over(self.failsafe, self.agent.commitments.inforce, abort)
        if error:
            log.warning("uav %d: hand-over failed: %s", self.opts.uav, error)
        elif self.failsafe.current is not None:
            cx, cy, radius, _ = self.failsafe.current
            log.info(
                "uav %d: handed over: AUTO, circling (%.0f, %.0f) m, radius %.0f m",
                self.opts.uav, cx, cy, radius,
            )  # fmt: skip

    @property
    def _journaled(self) -> int:
        """The last step this companion's journal holds (-1: none)."""
        return self.recovered.step if self.recovered is not None else -1

    def _run_realtime(self, stop: Callable[[], bool], budget: int) -> None:
        if self._k is None:
            self.mesh.join()
            if self.recovered is not None:
                self.steps_done = self.recovered.steps
        while not stop() and self.steps_done < budget:
            self.link.poll(0.02)  # and our HEARTBEAT when due
            if not self._check_link() or not self.link.state.has_pose:
                continue
            self._measure()
            t = self.link.state.time_s
            lead = LEAD * self.dt
            if self._k is None:
                self._k = max(math.ceil((t + lead) / self.dt - 1e-9), self._journaled + 1)
            if t + lead + 1e-6 >= self._k * self.dt:
                k = math.floor((t + lead) / self.dt + 1e-6)
                self.step(k, ahead=k * self.dt - t)
                self._k = k + 1

    def _lockstep_start(self) -> int:
        """The first step to fly in lockstep: the simulator's current step, or the one after the last
        journaled step when the journal already holds the current one (its bundle may not have gone
        out: an empty bundle stands in, so that no peer waits for it)."""
        now = self._vehicle_step()
        k = max(now, self._journaled + 1)
        if k > now:
            s = self.link.state
            self.mesh.publish(now, [], position=(s.x, s.y))
            self.link.command_long(LOCKSTEP_COMMAND, k)
        return k

    def _run_lockstep(self, stop: Callable[[], bool], budget: int) -> None:
        """Steps from the current one (`_k`) up to `budget` (a step number)."""
        self.link.on_poll = None  # one command per step: nothing repeated between steps
        if self._k is None:
            self._k = self._joined = self._lockstep_start()
            self.mesh.join()
        # the peers' bundles of the step before we joined went out before we listened
        k, joined = self._k, self._joined
        while not stop() and k < budget:
            said = time.monotonic()
            while not stop() and self.link.state.time_s + 1e-6 < k * self.dt:
                self.link.poll(0.05)
                if time.monotonic() - said < 1.0:
                    continue
                said = time.monotonic()
                self.link.send_heartbeat()  # stay the vehicle's peer however long the swarm waits
                if self._check_link() and self._resync:
                    # back after a lost link: say "ready" again (a restarted simulator has not heard
                    # it; duplicates are harmless) and ask for the current step's state
                    self.link.command_long(LOCKSTEP_COMMAND, k)
                    self.link.command_long(LOCKSTEP_COMMAND, 0)
                    self._let_a_rewound_vehicle_catch_up(k)
            if stop():
                return
            if self._resync:
                k = joined = self._k = self._joined = self._catch_up(k)
            self.camera.wait_until(round(k * self.dt * 1e6), PEER_WAIT_S)
            peers = self.mesh.alive_peers() - {self.opts.uav}
            if k > joined and peers:
                missing = self.mesh.wait_for(k - 1, peers, PEER_WAIT_S)
                if missing:
                    log.warning("uav %d: step %d: no messages from %s", self.opts.uav, k, sorted(missing))
            self._measure()
            self.step(k)
            self.link.command_long(LOCKSTEP_COMMAND, k + 1)
            k = self._k = k + 1

    def _vehicle_step(self) -> int:
        """The lockstep step the vehicle's latest position is at."""
        return round(self.link.state.time_s / self.dt)

    def _let_a_rewound_vehicle_catch_up(self, k: int) -> None:
        """After a lost link, in lockstep: a restarted simulator that resumed from a step before the
        one we flew last (it was killed after its telemetry of a step went out and before it saved
        that step) flies on, on the commands in force, until it is at step k again: we say "ready"
        for its next step (the other companions do the same)."""
        now = self._vehicle_step()
        if now < k - 1:
            log.warning(
                "uav %d: the vehicle resumed at step %d, behind us: releasing it to step %d",
                self.opts.uav,
                now,
                now + 1,
            )
            self.link.command_long(LOCKSTEP_COMMAND, now + 1)

    def _catch_up(self, k: int) -> int:
        """After a lost link, in lockstep: the step the vehicle is at now (it may have flown on
        without its companion), announced to the peers by an empty bundle of the step before, then
        join the mesh again."""
        now = self._vehicle_step()
        if now > k:
            log.warning(
                "uav %d: the vehicle went on without us: steps %d..%d not flown", self.opts.uav, k, now - 1
            )
            s = self.link.state
            self.mesh.publish(now - 1, [], position=(s.x, s.y))
            k = now
        self._resync = False
        self.mesh.join()
        return k

    def report(self) -> dict:
        """The companion's end-of-run record (what it learned, what it dropped)."""
        return {
            "uav": self.opts.uav,
            "steps": self.steps_done,
            "found_cells": sorted(int(c) for c in self.agent.found),
            "task": self.agent.task,
            "rejected_mavlink": self.link.rejected,
            "mavlink_signed": self.link.signed,
            "mavlink_unauthenticated": self.link.unauthenticated,
            "mavlink_wrong_system": self.link.wrong_system,
            "refused": {"mesh": self.mesh.refusals.summary(), "mavlink": self.link.refusals.summary()},
            "rejected_camera": self.camera.rejected,
            "mesh": asdict(self.mesh.stats),
            "plan_vs_flight": self.tracker.summary(),
            "command_mode": self.opts.command_mode,
            "airframe_warnings": self.airframe_warnings,
            "fence_uploaded": self.fence_uploaded,
            "failsafe_armed": self.failsafe is not None,
            "failsafe_uploads": self.failsafe.uploads if self.failsafe is not None else 0,
            "fence_exits": self.guard.exits,
            "guard": self.guard.state.value,
            "restarted_from_step": self._journaled,
            "fault_dropped": self.faults.dropped,
            "journal_records": None if self.journal is None else self.journal.records,
        }

    def close(self) -> None:
        if self.journal is not None:
            self.journal.close()
        for f in (self._log_file, self._plan_file):
            if f is not None:
                f.close()
        if self.opts.out is not None:
            path = self.opts.out / f"uav{self.opts.uav}.json"
            path.write_text(json.dumps(self.report(), indent=2) + "\n")
            log.info("uav %d: %d steps flown; report in %s", self.opts.uav, self.steps_done, path)


def camera_key_of(mission: Mission, uav: int) -> str:
    return camera_key(mission.mesh.key_prefix, mission.name, uav)
