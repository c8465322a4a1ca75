"""One simulated vehicle's autopilot logic: arming, modes, guidance and failsafes.

Pure state and rules, no sockets or clocks: every method takes the simulated time `t` (s) and,
where it matters, the vehicle's pose in the local frame (x east, y north, heading CCW from east).
Guidance answers with the *turn per sampling step* it wants (rad, CCW positive); the flight model
limits and integrates it (see `dynamics.flight`).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from sim_vehicles.modes import Behaviour, Flavour, Mode
from sim_vehicles.protocols.params import ParamStore

SETPOINT_RATE_WINDOW = 1.0  # s: PX4 OFFBOARD needs > 2 setpoints in this window...
SETPOINT_MAX_GAP = 0.5  # s: ...and the last one this recent


def _wrap(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi


@dataclass
class Orbit:
    """Fly to (x, y), then circle it clockwise (ArduPlane's default loiter direction)."""

    x: float
    y: float
    radius: float
    arrived: bool = False


@dataclass(frozen=True)
class HeadingHold:
    """Hold a heading (rad CCW from east) until `expires` (simulated s)."""

    heading: float
    expires: float


@dataclass(frozen=True)
class RateHold:
    """Turn at `rate` (rad/s, CCW positive) until `expires` (simulated s)."""

    rate: float
    expires: float


Nav = Orbit | HeadingHold | RateHold | None  # None: wings level, straight on


@dataclass(frozen=True)
class Waypoint:
    """A flyable mission item in the local frame; `up` None keeps the altitude."""

    seq: int
    command: int
    x: float
    y: float
    up: float | None


class Vehicle:
    """Arming, flight mode, guidance target and failsafes of one vehicle."""

    def __init__(
        self, index: int, flavour: Flavour, params: ParamStore, home: tuple[float, float],
        alt: float, step: float,
    ) -> None:
        self.index, self.sysid = index, index + 1
        self.flavour, self.params = flavour, params
        self.home = home
        self.last_xy = home
        self.step = step
        self.armed = False
        self.mode: Mode = flavour.by_name(flavour.initial)
        self.nav: Nav = None
        self.speed = params.value("cruise_speed")
        self.alt_target = alt
        self.mission: list[Waypoint] = []
        self.mission_index = 0
        self.setpoints: deque[float] = deque(maxlen=3)
        self.offboard_nav: Nav = None
        self.texts: list[tuple[int, str]] = []  # STATUSTEXTs to send (severity, text)
        self.reached: list[int] = []  # mission seqs reached, for MISSION_ITEM_REACHED

    # ---- queries ------------------------------------------------------------------------
    @property
    def loiter_radius(self) -> float:
        return self.params.value("loiter_radius")

    @property
    def turn_limit(self) -> float:
        """Turn limit per sampling step (rad)."""
        return math.radians(self.params.value("turn_limit"))

    @property
    def current_seq(self) -> int:
        if self.mission and self.mission_index < len(self.mission):
            return self.mission[self.mission_index].seq
        return 0

    def say(self, text: str, severity: int = mavlink.MAV_SEVERITY_INFO) -> None:
        self.texts.append((severity, text))

    # ---- commands -----------------------------------------------------------------------
    def arm(self, armed: bool) -> int:
        if armed != self.armed:
            self.armed = armed
            self.say("Throttle armed" if armed else "Throttle disarmed")
        return mavlink.MAV_RESULT_ACCEPTED

    def set_mode(self, custom_mode: int, t: float, x: float, y: float) -> int:
        mode = self.flavour.by_custom(custom_mode)
        if mode is None:
            return mavlink.MAV_RESULT_FAILED
        if mode == self.mode:
            return mavlink.MAV_RESULT_ACCEPTED
        if mode.behaviour is Behaviour.OFFBOARD and not self._stream_ok(t):
            self.say("Offboard: no setpoint stream", mavlink.MAV_SEVERITY_WARNING)
            return mavlink.MAV_RESULT_TEMPORARILY_REJECTED
        if mode.behaviour is Behaviour.AUTO and not self.mission:
            self.say("No mission", mavlink.MAV_SEVERITY_WARNING)
            return mavlink.MAV_RESULT_FAILED
        self._enter(mode, x, y)
        return mavlink.MAV_RESULT_ACCEPTED

    def reposition(
        self, x: float, y: float, target: tuple[float, float], up: float | None, radius: float,
        change_mode: bool,
    ) -> int:
        """MAV_CMD_DO_REPOSITION: fly to `target`, then loiter (ArduPlane GUIDED / PX4 Hold)."""
        go_to = self.flavour.by_name(self.flavour.reposition)
        if self.mode != go_to and not change_mode:
            return mavlink.MAV_RESULT_FAILED
        if self.mode != go_to:
            self._enter(go_to, x, y)
        self.nav = Orbit(target[0], target[1], radius if radius > 0 else self.loiter_radius)
        if up is not None:
            self.alt_target = up
        return mavlink.MAV_RESULT_ACCEPTED

    def change_heading(self, t: float, x: float, y: float, kind: int, heading: float) -> int:
        """MAV_CMD_GUIDED_CHANGE_HEADING (ArduPlane): hold a heading, or cancel (kind 2)."""
        if self.mode.behaviour is not Behaviour.GUIDED:
            return mavlink.MAV_RESULT_FAILED
        if kind == 2:
            self.nav = Orbit(x, y, self.loiter_radius, arrived=True)
        else:
            self.nav = HeadingHold(heading, t + self.params.value("guided_timeout"))
        return mavlink.MAV_RESULT_ACCEPTED

    def change_speed(self, speed: float) -> int:
        """DO_CHANGE_SPEED / GUIDED_CHANGE_SPEED: new cruise speed (negative: no change)."""
        if speed < 0:
            return mavlink.MAV_RESULT_ACCEPTED
        spec = self.params.specs[0]
        if self.params.grid or not spec.lo <= speed <= spec.hi:
            return mavlink.MAV_RESULT_DENIED
        self.speed = speed
        return mavlink.MAV_RESULT_ACCEPTED

    def set_param(self, index: int, value: float) -> bool:
        ok = self.params.set(index, value)
        if ok and self.params.specs[index].key == "cruise_speed":
            self.speed = value
        return ok

    def turn_rate(self, t: float, rate: float) -> bool:
        """The bundled simulator's direct turn-rate command (rad/s CCW); False if not in control."""
        if self.flavour.name == "px4":
            self.setpoints.append(t)
            self.offboard_nav = RateHold(rate, math.inf)
            if self.mode.behaviour is Behaviour.OFFBOARD:
                self.nav = self.offboard_nav
                return True
            return False
        if self.mode.behaviour is not Behaviour.GUIDED:
            return False
        self.nav = RateHold(rate, t + self.params.value("guided_timeout"))
        return True

    def position_target(self, t: float, target: tuple[float, float] | None, up: float | None) -> bool:
        """SET_POSITION_TARGET_*: PX4 flies to the point in OFFBOARD, ArduPlane takes only altitude."""
        if self.flavour.name == "px4":
            self.setpoints.append(t)
            if target is not None:
                old = self.offboard_nav
                if not (isinstance(old, Orbit) and (old.x, old.y) == target):
                    self.offboard_nav = Orbit(target[0], target[1], self.loiter_radius)
            if self.mode.behaviour is not Behaviour.OFFBOARD:
                return False
            self.nav = self.offboard_nav or self.nav
        elif self.mode.behaviour is not Behaviour.GUIDED:
            return False
        if up is not None:
            self.alt_target = up
        return True

    def set_mission(self, waypoints: list[Waypoint]) -> None:
        self.mission, self.mission_index = waypoints, 0
        if self.mode.behaviour is Behaviour.AUTO:
            self._next_waypoint()

    def set_current(self, seq: int) -> bool:
        index = next((i for i, w in enumerate(self.mission) if w.seq == seq), None)
        if index is None:
            return False
        self.mission_index = index
        if self.mode.behaviour is Behaviour.AUTO:
            self._next_waypoint()
        return True

    # ---- guidance -----------------------------------------------------------------------
    def steer(self, t: float, x: float, y: float, heading: float) -> float:
        """Apply failsafes, then the turn per step (rad) the current guidance asks for."""
        self.last_xy = (x, y)
        self._failsafes(t, x, y)
        nav = self.nav
        if nav is None:
            return 0.0
        if isinstance(nav, RateHold):
            return nav.rate * self.step
        if isinstance(nav, HeadingHold):
            return _wrap(nav.heading - heading)
        if not nav.arrived:
            self._check_arrival(nav, x, y, heading)
        if not nav.arrived:
            return _wrap(math.atan2(nav.y - y, nav.x - x) - heading)
        return self._orbit_turn(nav, x, y, heading)

    def _orbit_turn(self, nav: Orbit, x: float, y: float, heading: float) -> float:
        dx, dy = x - nav.x, y - nav.y
        r = math.hypot(dx, dy)
        course = math.atan2(dy, dx) - math.pi / 2 - math.atan2(r - nav.radius, 0.5 * nav.radius)
        feed_forward = -self.speed * self.step / nav.radius if r < 2 * nav.radius else 0.0
        return _wrap(course - heading) + feed_forward

    def _check_arrival(self, nav: Orbit, x: float, y: float, heading: float) -> None:
        radius = self.params.value("wp_radius")
        dx, dy = nav.x - x, nav.y - y
        d = math.hypot(dx, dy)
        behind = dx * math.cos(heading) + dy * math.sin(heading) < 0
        if d > radius and not (behind and d < 3 * radius):
            return
        nav.arrived = True
        if self.mode.behaviour is Behaviour.AUTO and self.mission_index < len(self.mission):
            wp = self.mission[self.mission_index]
            self.reached.append(wp.seq)
            self.say(f"Reached waypoint #{wp.seq}")
            if wp.command != mavlink.MAV_CMD_NAV_LOITER_UNLIM:
                self.mission_index += 1
                self._next_waypoint()

    def _failsafes(self, t: float, x: float, y: float) -> None:
        if self.mode.behaviour is Behaviour.GUIDED and isinstance(self.nav, HeadingHold | RateHold):
            if t > self.nav.expires:
                timeout = self.params.value("guided_timeout")
                self._enter(self.flavour.by_name(self.flavour.hold), x, y)
                self.say(f"GUIDED: no guidance for {timeout:g} s, LOITER", mavlink.MAV_SEVERITY_WARNING)
        elif self.mode.behaviour is Behaviour.OFFBOARD and (
            not self.setpoints or t - self.setpoints[-1] > self.params.value("guided_timeout")
        ):
            self._enter(self.flavour.by_name(self.flavour.hold), x, y)
            self.say("Offboard setpoints lost: HOLD", mavlink.MAV_SEVERITY_WARNING)

    # ---- internals ----------------------------------------------------------------------
    def _stream_ok(self, t: float) -> bool:
        s = self.setpoints
        return (
            len(s) == s.maxlen and t - s[0] <= SETPOINT_RATE_WINDOW and t - s[-1] <= SETPOINT_MAX_GAP
        )

    def _enter(self, mode: Mode, x: float, y: float) -> None:
        self.mode, self.last_xy = mode, (x, y)
        b = mode.behaviour
        if b is Behaviour.STRAIGHT:
            self.nav = None
        elif b in (Behaviour.LOITER, Behaviour.GUIDED):
            self.nav = Orbit(x, y, self.loiter_radius, arrived=True)
        elif b is Behaviour.RTL:
            self.nav = Orbit(self.home[0], self.home[1], self.loiter_radius)
        elif b is Behaviour.OFFBOARD:
            self.nav = self.offboard_nav or Orbit(x, y, self.loiter_radius, arrived=True)
        else:
            self._next_waypoint()

    def _next_waypoint(self) -> None:
        """Point the AUTO guidance at the current mission item, ending the mission when done."""
        while self.mission_index < len(self.mission):
            wp = self.mission[self.mission_index]
            if wp.command == mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH:
                self._enter(self.flavour.by_name(self.flavour.rtl), *self.last_xy)
                return
            if math.isfinite(wp.x):
                self.nav = Orbit(wp.x, wp.y, self.loiter_radius)
                if wp.up is not None:
                    self.alt_target = wp.up
                return
            self.mission_index += 1
        self.say("Mission complete")
        self._enter(self.flavour.by_name(self.flavour.mission_end), *self.last_xy)
