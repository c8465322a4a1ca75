"""Plan versus flight, and what the companion does when the vehicle leaves the area.

`PlanTracker`: every steered step k it measures how far the vehicle is, at time k·dT, from where
the plan put it (position in metres, heading in degrees), keeps the figures for the report and
warns when the error stays beyond a bound. `RegionGuard`: outside the region plus its margin the
companion stops flying the plan and brings the vehicle back inside; not back in time, it leaves the
vehicle to the autopilot for good. Details: docs/companion.md, "Plan versus flight".
"""

from __future__ import annotations

import logging
import math
from collections import deque
from dataclasses import dataclass
from enum import Enum

import msgspec
import numpy as np

from companion.core.geometry import ConvexPolygon
from companion.node.fence import nearest_inside

log = logging.getLogger("companion")

WARN_STEPS = 3  # consecutive steps beyond the bound before a warning
PATIENCE_STEPS = 30  # steps a vehicle outside the fence gets, beyond the way back, to come back inside


@dataclass(frozen=True)
class PlanError:
    """Where the plan put the UAV at step k, where the vehicle was, and the difference."""

    step: int
    planned: tuple[float, float, float]  # x, y, heading (rad CCW from east)
    flown: tuple[float, float, float]
    position_m: float
    heading_deg: float


class Percentiles(msgspec.Struct, frozen=True):
    """The median, 95th percentile and maximum of a series of errors (None: no error measured)."""

    median: float | None
    p95: float | None
    max: float | None


class PlanSummary(msgspec.Struct, frozen=True):
    """One UAV's plan versus flight (the "plan_vs_flight" of its report)."""

    steps: int
    missed: int
    bound_m: float
    warnings: int
    position_m: Percentiles
    heading_deg: Percentiles


def percentiles(values: list[float]) -> Percentiles:
    """The `Percentiles` of `values`."""
    if not values:
        return Percentiles(None, None, None)
    a = np.asarray(values)
    return Percentiles(float(np.median(a)), float(np.percentile(a, 95)), float(a.max()))


class PlanTracker:
    """Per-step plan-versus-flight errors of one UAV."""

    def __init__(
        self, uav: int, speed: float, dt: float, bound_m: float, warn_steps: int = WARN_STEPS
    ) -> None:
        self.uav, self.speed, self.dt = uav, speed, dt
        self.bound_m, self.warn_steps = bound_m, warn_steps
        self.pending: deque[tuple[int, float, float, float]] = deque()  # plans not yet measured
        self._early: tuple[float, float, float, float] | None = None  # last sample before the next plan
        self.errors: list[PlanError] = []
        self.missed = 0  # plans whose time passed without telemetry near it
        self.warnings = 0
        self._over = 0

    def expect(self, k: int, x: float, y: float, heading: float) -> None:
        """The plan puts the UAV at (x, y, heading) at step k."""
        self.pending.append((k, x, y, heading))

    def cancel(self) -> None:
        """Forget the plans not measured yet (the vehicle is no longer flying them)."""
        self.pending.clear()

    def measure(self, t: float, x: float, y: float, heading: float) -> PlanError | None:
        """Measure the oldest pending plan once vehicle time `t` has reached its time.

        Compare the oldest pending plan with the vehicle's pose once vehicle time `t` has reached
        the plan's time: the pose of the last sample before that time if it was at most half a step
        early, else this one; the planned point is moved along its heading by the sample's offset
        from the plan's time. A plan without a sample within half a step of its time is missed."""
        half = 0.5 * self.dt
        while self.pending:
            when = self.pending[0][0] * self.dt
            if t < when - 1e-6:
                self._early = (t, x, y, heading)
                return None
            early, self._early = self._early, None
            if early is not None and when - early[0] <= half:
                t, x, y, heading = early
                break
            if t - when <= half:
                break
            self.pending.popleft()  # its time passed by more than half a step without telemetry
            self.missed += 1
        if not self.pending:
            return None
        k, px, py, ph = self.pending.popleft()
        offset = t - k * self.dt
        px, py = px + self.speed * offset * math.cos(ph), py + self.speed * offset * math.sin(ph)
        position = math.hypot(x - px, y - py)
        turn = math.degrees(abs(math.remainder(heading - ph, 2 * math.pi)))
        error = PlanError(k, (px, py, ph), (x, y, heading), position, turn)
        self.errors.append(error)
        self._over = self._over + 1 if position > self.bound_m else 0
        if self._over == self.warn_steps:
            self.warnings += 1
            log.warning(
                "uav %d: the vehicle has been over %.0f m from its plan for %d steps (%.0f m at step %d)",
                self.uav,
                self.bound_m,
                self.warn_steps,
                position,
                k,
            )
        return error

    def summary(self) -> PlanSummary:
        """The figures of the errors measured so far, for the companion's report."""
        return PlanSummary(
            steps=len(self.errors),
            missed=self.missed,
            bound_m=self.bound_m,
            warnings=self.warnings,
            position_m=percentiles([e.position_m for e in self.errors]),
            heading_deg=percentiles([e.heading_deg for e in self.errors]),
        )


class Guard(Enum):
    """What the companion does about the fence: fly the plan, return inside, or leave it to the autopilot."""

    INSIDE = "inside"  # flying the plan
    RETURNING = "returning"  # left the fence: repositioned back inside, not flying the plan
    RELEASED = "released"  # did not come back: left to the autopilot for good


class RegionGuard:
    """The companion's reaction to the vehicle leaving the region plus its margin."""

    def __init__(
        self,
        uav: int,
        region: ConvexPolygon,
        fence: ConvexPolygon,
        depth: float,
        step_length: float,
        patience: int = PATIENCE_STEPS,
    ) -> None:
        self.uav, self.region, self.fence = uav, region, fence
        self.depth, self.step_length, self.patience = depth, step_length, patience
        self.state = Guard.INSIDE
        self.exits = 0
        self._deadline = 0

    def check(self, k: int, x: float, y: float) -> tuple[float, float] | None:
        """Update the state with the pose of step k; the point to reposition to when it just left."""
        if self.state is Guard.INSIDE and not self.fence.contains(x, y):
            self.state = Guard.RETURNING
            self.exits += 1
            target = nearest_inside(self.region, x, y, self.depth)
            way_back = math.hypot(target[0] - x, target[1] - y) / self.step_length
            self._deadline = k + math.ceil(way_back) + self.patience
            log.warning(
                "uav %d: step %d: the vehicle left the region plus its margin at (%.0f, %.0f): "
                "not flying the plan, repositioning to (%.0f, %.0f)",
                self.uav,
                k,
                x,
                y,
                *target,
            )
            return target
        if self.state is Guard.RETURNING:
            if self.region.contains(x, y):
                self.state = Guard.INSIDE
                log.warning(
                    "uav %d: step %d: the vehicle is back inside the region: flying the plan", self.uav, k
                )
            elif k >= self._deadline:
                self.state = Guard.RELEASED
                log.warning(
                    "uav %d: step %d: the vehicle did not come back inside the region: "
                    "not steering any more, the autopilot's fence and failsafes act",
                    self.uav,
                    k,
                )
        return None
