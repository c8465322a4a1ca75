"""The lockstep loop: each step waits for its pose, camera frame and peers, then says it is done."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable

from companion.node.camera_feed import CameraFeed
from companion.node.mesh import Mesh
from companion.node.pilot import Pilot
from companion.node.vehicle_link import VehicleLink
from companion.node.watch import VehicleWatch

log = logging.getLogger("companion")

LOCKSTEP_COMMAND = 31010  # MAV_CMD_USER_1: "lockstep: ready for step param1"
PEER_WAIT_S = 30.0  # how long to wait for a live peer's messages before going on


class LockstepLoop:
    """Steps in lockstep with the bundled simulator, so a distributed run reproduces the batch engine's.

    The simulator advances only when every companion has reported its step done (docs/simulator.md).
    """

    def __init__(
        self, pilot: Pilot, watch: VehicleWatch, link: VehicleLink, mesh: Mesh, camera: CameraFeed
    ) -> None:
        self.pilot, self.watch, self.link, self.mesh, self.camera = pilot, watch, link, mesh, camera
        self.uav = pilot.opts.uav
        self.k: int | None = None  # the next step to fly (None: not started)
        self.joined = 0  # the step this companion joined the mesh at

    def ask_for_state(self) -> None:
        """Ask the simulator to send the current step's state again."""
        self.link.command_long(LOCKSTEP_COMMAND, 0)

    def budget_after(self, steps: int) -> int:
        """The budget (a step number) that flies `steps` more steps."""
        return (self.k or 0) + steps

    def _vehicle_step(self) -> int:
        """The lockstep step the vehicle's latest position is at."""
        return round(self.link.state.time_s / self.pilot.dt)

    def _start(self) -> int:
        """The first step to fly: the simulator's current step, or the one after the last journaled.

        The step after the last journaled one applies when the journal already holds the current
        step (its bundle may not have gone out: an empty bundle stands in, so that no peer waits
        for it).
        """
        now = self._vehicle_step()
        k = max(now, self.pilot.journaled + 1)
        if k > now:
            s = self.link.state
            self.mesh.publish(now, [], position=(s.x, s.y))
            self.link.command_long(LOCKSTEP_COMMAND, k)
        return k

    def run(self, stop: Callable[[], bool], budget: int) -> None:
        """Steps from the current one (`k`) up to `budget` (a step number)."""
        self.link.on_poll = None  # one command per step: nothing repeated between steps
        if self.k is None:
            self.k = self.joined = self._start()
            self.mesh.join()
        # the peers' bundles of the step before we joined went out before we listened
        k = self.k
        while not stop() and k < budget:
            self._wait_for_vehicle(stop, k)
            if stop():
                return
            if self.watch.resync:
                k = self.k = self.joined = self._catch_up(k)
            self.camera.wait_until(round(k * self.pilot.dt * 1e6), PEER_WAIT_S)
            peers = self.mesh.alive_peers() - {self.uav}
            if k > self.joined and peers:
                missing = self.mesh.wait_for(k - 1, peers, PEER_WAIT_S)
                if missing:
                    log.warning("uav %d: step %d: no messages from %s", self.uav, k, sorted(missing))
            self.pilot.measure()
            self.pilot.step(k)
            self.link.command_long(LOCKSTEP_COMMAND, k + 1)
            k = self.k = k + 1

    def _wait_for_vehicle(self, stop: Callable[[], bool], k: int) -> None:
        """Poll until the vehicle's telemetry reaches step k.

        Meanwhile the companion stays the vehicle's peer however long the swarm waits, and says
        "ready" again after a lost link.
        """
        said = time.monotonic()
        while not stop() and self.link.state.time_s + 1e-6 < k * self.pilot.dt:
            self.link.poll(0.05)
            if time.monotonic() - said < 1.0:
                continue
            said = time.monotonic()
            self.link.send_heartbeat()  # stay the vehicle's peer however long the swarm waits
            if self.watch.check_link() and self.watch.resync:
                # back after a lost link: say "ready" again (a restarted simulator has not heard
                # it; duplicates are harmless) and ask for the current step's state
                self.link.command_long(LOCKSTEP_COMMAND, k)
                self.ask_for_state()
                self._let_a_rewound_vehicle_catch_up(k)

    def _let_a_rewound_vehicle_catch_up(self, k: int) -> None:
        """After a lost link: release a simulator that resumed behind us, one step at a time, to step k.

        A restarted simulator may resume from a step before the one we flew last (it was killed
        after its telemetry of a step went out and before it saved that step). It flies on, on the
        commands in force, until it is at step k again: we say "ready" for its next step (the other
        companions do the same).
        """
        now = self._vehicle_step()
        if now < k - 1:
            log.warning(
                "uav %d: the vehicle resumed at step %d, behind us: releasing it to step %d",
                self.uav,
                now,
                now + 1,
            )
            self.link.command_long(LOCKSTEP_COMMAND, now + 1)

    def _catch_up(self, k: int) -> int:
        """After a lost link: rejoin the mesh at the step the vehicle is at now; that step.

        The vehicle may have flown on without its companion; the step is announced to the peers by
        an empty bundle of the step before, then the companion joins the mesh again.
        """
        now = self._vehicle_step()
        if now > k:
            log.warning(
                "uav %d: the vehicle went on without us: steps %d..%d not flown", self.uav, k, now - 1
            )
            s = self.link.state
            self.mesh.publish(now - 1, [], position=(s.x, s.y))
            k = now
        self.watch.resync = False
        self.mesh.join()
        return k
