"""The companion process: one per UAV, driving the core's Agent with real I/O (docs/companion.md).

Every sampling step k (vehicle time k * dT) it reads its vehicle's pose over MAVLink, takes the
camera's detections and the peers' step k-1 messages, calls `Agent.step` (`pilot`), commands the
vehicle while it is in its guided mode and publishes the outbox; in real time (`realtime`) or in
lockstep with the bundled simulator (`lockstep`). Before the first step it checks and readies the
vehicle (`preflight`), at the end it flies out the trajectory in force (`flyout`); a journal lets
a restarted companion go on without loss (docs/reliability.md, "Restart without loss").
"""

from __future__ import annotations

import logging
import threading

import msgspec

from companion.contracts.detections import camera_key
from companion.contracts.mission import Mission
from companion.core.warm import warm_up
from companion.node.camera_feed import CameraFeed
from companion.node.flyout import fly_out
from companion.node.lockstep import LockstepLoop
from companion.node.mesh import Mesh
from companion.node.pilot import CompanionOptions, Pilot
from companion.node.preflight import Preflight
from companion.node.realtime import RealtimeLoop
from companion.node.report import CompanionReport
from companion.node.target_watch import CANDIDATE, CONFIRMED, RETRACTED
from companion.node.vehicle_link import VEHICLE_WAIT_S, VehicleLink
from companion.node.watch import VehicleWatch

log = logging.getLogger("companion")


def default_vehicle_url(mission: Mission, uav: int) -> str:
    """The bundled simulator's endpoint of vehicle `uav` (it listens; the companion sends first)."""
    return f"udpout:{mission.sim.host}:{mission.vehicle_port(uav)}"


def camera_key_of(mission: Mission, uav: int) -> str:
    """The Zenoh key UAV `uav`'s camera publishes its detections on."""
    return camera_key(mission.mesh.key_prefix, mission.name, uav)


class Companion:
    """One UAV's companion: its pilot, vehicle watch, loop and preflight wired together.

    `run` returns when `stop` is set or the step budget is spent.
    """

    def __init__(self, opts: CompanionOptions, link: VehicleLink, mesh: Mesh, camera: CameraFeed) -> None:
        """Wire the pieces (JournalError for a journal of another mission)."""
        self.opts, self.link, self.mesh, self.camera = opts, link, mesh, camera
        self.pilot = Pilot(opts, link, mesh, camera)
        self.watch = VehicleWatch(self.pilot, link, mesh, opts.lockstep)
        self.loop: RealtimeLoop | LockstepLoop = (
            LockstepLoop(self.pilot, self.watch, link, mesh, camera)
            if opts.lockstep
            else RealtimeLoop(self.pilot, self.watch, link, mesh)
        )
        self.preflight = Preflight(self.pilot, self.watch, link)

    def run(self, stop: threading.Event, abort: threading.Event | None = None) -> int:
        """Fly the mission until its step budget is spent or `stop`, then close it (`flyout`); 0.

        `abort` (a second signal) cuts the closing short.
        """
        abort = abort if abort is not None else threading.Event()
        seconds = warm_up(self.opts.mission)  # no compiling inside the first real steps
        log.info("uav %d: algorithm ready in %.1f s", self.opts.uav, seconds)
        log.info("uav %d: waiting for the vehicle at %s", self.opts.uav, self.opts.vehicle_url)
        if not self.link.wait_heartbeat(VEHICLE_WAIT_S, stop.is_set):
            return 0  # stopped before the vehicle answered: nothing flown, nothing to close
        log.info("uav %d: vehicle system %d is up", self.opts.uav, self.link.state.system)
        self.preflight.connect()
        if isinstance(self.loop, LockstepLoop):
            self.loop.ask_for_state()  # the simulator resends the current step's state
        self.preflight.prepare(stop)
        budget = self.opts.steps if self.opts.steps is not None else self.opts.mission.steps
        self.loop.run(stop.is_set, budget)
        if self.pilot.steps_done and not abort.is_set():
            fly_out(self.pilot, self.loop, stopped=stop.is_set(), abort=abort)
        return 0

    def report(self) -> CompanionReport:
        """The companion's end-of-run record (what it learned, what it dropped)."""
        pilot, link, preflight = self.pilot, self.link, self.preflight
        return CompanionReport(
            uav=self.opts.uav,
            steps=pilot.steps_done,
            found_cells=sorted(int(c) for c in pilot.agent.found),
            candidate_cells=sorted(int(c) for c in pilot.agent.candidates),
            candidates_raised=pilot.targets.counts[CANDIDATE],
            confirmations=pilot.targets.counts[CONFIRMED],
            retractions=pilot.targets.counts[RETRACTED],
            task=pilot.agent.task,
            rejected_mavlink=link.rejected,
            mavlink_signed=link.signing.enabled,
            mavlink_unauthenticated=link.unauthenticated,
            mavlink_wrong_system=link.wrong_system,
            refused={"mesh": self.mesh.refusals.summary(), "mavlink": link.refusals.summary()},
            rejected_camera=self.camera.rejected,
            mesh=self.mesh.stats,
            plan_vs_flight=pilot.tracker.summary(),
            command_mode=self.opts.command_mode,
            airframe_warnings=preflight.airframe_warnings,
            fence_uploaded=preflight.fence_uploaded,
            failsafe_armed=pilot.failsafe is not None,
            failsafe_uploads=pilot.failsafe.uploads if pilot.failsafe is not None else 0,
            fence_exits=pilot.guard.exits,
            guard=pilot.guard.state.value,
            restarted_from_step=pilot.journaled,
            fault_dropped=pilot.faults.dropped,
            journal_records=None if pilot.journal is None else pilot.journal.records,
        )

    def close(self) -> None:
        """Close the journal and the logs, and write the report (`uav<N>.json`) next to them."""
        if self.pilot.journal is not None:
            self.pilot.journal.close()
        if self.pilot.logs is not None:
            self.pilot.logs.close()
        if self.opts.out is not None:
            path = self.opts.out / f"uav{self.opts.uav}.json"
            path.write_bytes(msgspec.json.format(msgspec.json.encode(self.report()), indent=2) + b"\n")
            log.info("uav %d: %d steps flown; report in %s", self.opts.uav, self.pilot.steps_done, path)
