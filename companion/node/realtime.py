"""The real-time loop: step k planned a quarter step before vehicle time k * dT, from the pose then."""

from __future__ import annotations

import math
from collections.abc import Callable

from companion.node.mesh import Mesh
from companion.node.pilot import Pilot
from companion.node.vehicle_link import VehicleLink
from companion.node.watch import VehicleWatch

# A step is planned LEAD of a step before it starts, from the pose predicted for its start, so that
# the command is in place when the autopilot begins the step (no one-step lag).
LEAD = 0.25


class RealtimeLoop:
    """Steps on the vehicle's clock, whatever its speed-up; the peers' messages are what has arrived."""

    def __init__(self, pilot: Pilot, watch: VehicleWatch, link: VehicleLink, mesh: Mesh) -> None:
        self.pilot, self.watch, self.link, self.mesh = pilot, watch, link, mesh
        self.k: int | None = None  # the next step to fly (None: not started)

    def budget_after(self, steps: int) -> int:
        """The budget that flies `steps` more steps (the loop counts the steps flown)."""
        return self.pilot.steps_done + steps

    def run(self, stop: Callable[[], bool], budget: int) -> None:
        """Fly steps until `stop` or `budget` steps have been flown in all."""
        pilot, link = self.pilot, self.link
        if self.k is None:
            self.mesh.join()
            if pilot.recovered is not None:
                pilot.steps_done = pilot.recovered.steps
        while not stop() and pilot.steps_done < budget:
            link.poll(0.02)  # and our HEARTBEAT when due
            if not self.watch.check_link() or not link.state.has_pose:
                continue
            pilot.measure()
            t = link.state.time_s
            lead = LEAD * pilot.dt
            if self.k is None:
                self.k = max(math.ceil((t + lead) / pilot.dt - 1e-9), pilot.journaled + 1)
            if t + lead + 1e-6 >= self.k * pilot.dt:
                k = math.floor((t + lead) / pilot.dt + 1e-6)
                pilot.step(k, ahead=k * pilot.dt - t)
                self.k = k + 1
