"""The Agent's command as MAVLink guidance, in one of four command modes, at the UAV's altitude layer.

| mode | MAVLink |
|---|---|
| `turn-rate` | SET_ATTITUDE_TARGET body yaw rate (the bundled simulator's direct steering) |
| `heading` | MAV_CMD_GUIDED_CHANGE_HEADING, led as ArduPlane's heading loop needs (`heading_lead`) |
| `reposition` | MAV_CMD_DO_REPOSITION to a point ahead on the commanded heading |
| `position-target` | SET_POSITION_TARGET_GLOBAL_INT to that point, streamed (PX4 OFFBOARD) |

Whenever steering (re)starts, and every `REASSERT_STEPS` steps, it also asserts the UAV's altitude
(`mission.altitude_of(uav)`; MAV_CMD_GUIDED_CHANGE_ALTITUDE in the modes whose command has no
altitude) and, if the autopilot cruises at another speed, the mission's speed (DO_CHANGE_SPEED).
"""

from __future__ import annotations

import math

import numpy as np

from companion.contracts.frames import LocalFrame, heading_to_yaw
from companion.contracts.mission import Mission
from companion.core.agent import Command
from companion.core.geometry import ConvexPolygon
from companion.node.airframe import heading_lead, turn_accel
from companion.node.vehicle_link import VehicleLink

COMMAND_MODES = ("turn-rate", "heading", "reposition", "position-target")
# Guidance is streamed (vehicle seconds between repeats of the current command) so that the
# autopilot's guidance timeout never fires between steps; PX4 OFFBOARD needs more than 2 Hz.
STREAM_PERIOD_S = {"turn-rate": 0.5, "heading": 0.5, "position-target": 0.2}
LEAD_STEPS, LEAD_MIN_M = 5, 200.0  # waypoint modes fly to a point this far ahead (see lead_point)
REASSERT_STEPS = 10
FENCE_CLEARANCE_M = 5.0  # how far inside the fence a lead point stays
WITHOUT_ALTITUDE = ("turn-rate", "heading")


class Guidance:
    """One UAV's guidance in one command mode."""

    def __init__(self, link: VehicleLink, frame: LocalFrame, mission: Mission, uav: int, mode: str) -> None:
        if mode not in COMMAND_MODES:
            raise ValueError(f"unknown command mode {mode!r} (one of {', '.join(COMMAND_MODES)})")
        k = mission.kinematics
        self.link, self.frame, self.mode = link, frame, mode
        self.altitude = mission.altitude_of(uav)
        self.kinematics = k
        self.speed = k.speed
        self.accel = turn_accel(k)
        self.lead = max(LEAD_STEPS * k.speed * k.step, LEAD_MIN_M)
        self.set_speed = False  # the autopilot cruises at another speed: command the mission's
        self.last_send = -math.inf  # vehicle time of the latest guidance
        self.last: tuple[Command, tuple[float, float]] | None = None
        self.point: tuple[float, float] | None = None  # position-target: a point flown to (go_to)
        self.fence: ConvexPolygon | None = None  # lead points stay inside it
        self._since_assert: int | None = None  # steps since the altitude and speed were asserted

    def step(self, command: Command, position: tuple[float, float]) -> None:
        """Send step `command`, planned from `position` (the UAV's position at the step)."""
        if self._since_assert is None or self._since_assert >= REASSERT_STEPS:
            self.assert_flight()
        self._since_assert = (self._since_assert or 0) + 1
        self.last, self.point = (command, position), None
        self._send(command, position)

    def paused(self) -> None:
        """Not steering this step: assert altitude and speed again when steering restarts."""
        self._since_assert = None

    def due(self, now: float) -> bool:
        """Whether the current command should be repeated at vehicle time `now` (streamed modes)."""
        period = STREAM_PERIOD_S.get(self.mode)
        current = self.last is not None or self.point is not None
        return period is not None and current and now - self.last_send >= period

    def repeat(self) -> None:
        if self.point is not None:
            self.hold(*self.point)
        elif self.last is not None:
            self._send(*self.last)

    def assert_flight(self) -> None:
        if self.mode in WITHOUT_ALTITUDE:
            self.link.commands.change_altitude(self.altitude)
        if self.set_speed:
            self.link.commands.change_speed(self.speed)

    def go_to(self, x: float, y: float) -> None:
        """Fly to local (x, y) at the UAV's altitude and circle there, instead of the plan.

        In PX4 OFFBOARD: the position target, streamed from now on, in `position-target` (a DO_REPOSITION
        would switch to Hold); DO_REPOSITION in the other modes.
        """
        self.last = None
        if self.mode == "position-target":
            self.point = (x, y)
            self.hold(x, y)
            return
        self.point = None
        lat, lon, _ = self.frame.to_geodetic(x, y)
        self.link.commands.reposition(lat, lon, self.altitude)
        self.last_send = self.link.state.time_s

    def hold_course(self, x: float, y: float, heading: float) -> None:
        """Fly on along `heading` from (x, y) until the first step.

        The position target a lead ahead, streamed from now on (what PX4 needs streamed before it accepts
        OFFBOARD, and after).
        """
        self.last = None
        self.point = (x + self.lead * math.cos(heading), y + self.lead * math.sin(heading))
        self.hold(*self.point)

    def hold(self, x: float, y: float) -> None:
        """A position setpoint at (x, y)."""
        lat, lon, _ = self.frame.to_geodetic(x, y)
        self.link.commands.position_target(lat, lon, self.altitude)
        self.last_send = self.link.state.time_s

    def _send(self, command: Command, position: tuple[float, float]) -> None:
        if self.mode == "turn-rate":
            self.link.commands.turn_rate(-command.heading_rate)  # MAVLink yaw rate is clockwise-positive
        elif self.mode == "heading":
            heading = command.heading + heading_lead(self.kinematics, command.heading_rate)
            self.link.commands.change_heading(math.degrees(heading_to_yaw(heading)), self.accel)
        elif self.mode == "reposition":
            self.go_to(*self.lead_point(command, position))
        else:
            self.hold(*self.lead_point(command, position))
        self.last_send = self.link.state.time_s

    def lead_point(self, command: Command, position: tuple[float, float]) -> tuple[float, float]:
        return lead_point(position, command.heading, self.lead, self.fence)


def lead_point(
    position: tuple[float, float], heading: float, lead: float, fence: ConvexPolygon | None
) -> tuple[float, float]:
    """Where the waypoint modes fly: `lead` ahead of the step's position on the commanded heading.

    The next planned path point is one step (v dT) away, inside the acceptance radius of an
    autopilot (WP_RADIUS, NAV_ACC_RAD): it would count as reached at once and the vehicle would
    loiter around it. A point LEAD_STEPS steps (at least LEAD_MIN_M) out on the heading the plan
    reaches after its first step turns the vehicle onto that heading now. It stays inside the
    fence (PX4 refuses a DO_REPOSITION beyond its geofence): nearer the vehicle when the heading
    points out of the area.
    """
    x, y = position
    c, s = math.cos(heading), math.sin(heading)
    if fence is not None:
        lead = min(lead, _exit_distance(fence, x, y, c, s))
    return x + lead * c, y + lead * s


def _exit_distance(fence: ConvexPolygon, x: float, y: float, c: float, s: float) -> float:
    """How far from (x, y) along (c, s) the fence is left, less FENCE_CLEARANCE_M.

    Inf if never; from outside the fence, inf too (the full lead: the region guard acts there).
    """
    along = fence.normals @ np.array([c, s])
    room = fence.offsets - fence.normals @ np.array([x, y])
    if np.any(room < 0):
        return math.inf
    out = along > 1e-12
    return float(np.min(room[out] / along[out])) - FENCE_CLEARANCE_M if np.any(out) else math.inf
