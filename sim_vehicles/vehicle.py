"""One simulated vehicle's autopilot logic: arming, modes, guidance, fence and failsafes.

Pure state and rules, no sockets or clocks: every method takes the simulated time `t` (s) and,
where it matters, the vehicle's pose in the local frame (x east, y north, heading CCW from east).
Guidance answers with a `Turn` (`nav_targets`): the bank angle ArduPlane's laws ask for
(`dynamics.navigation`) or the turn rate of the simulator's turn-rate command; the flight model
limits and integrates it (`dynamics.flight`). The modes, commands, fence and failsafes of each
flavour (ArduPilot, PX4) are described in docs/simulator.md.
"""

from __future__ import annotations

import math
from collections import deque

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from sim_vehicles.dynamics import navigation as nav
from sim_vehicles.fence import Fence
from sim_vehicles.modes import Behaviour, Flavour, Mode
from sim_vehicles.nav_targets import HeadingHold, Leg, Loiter, Nav, RateHold, Turn, Waypoint
from sim_vehicles.protocols.params import ParamStore

SETPOINT_RATE_WINDOW = 1.0  # s: PX4 OFFBOARD needs > 2 setpoints in this window...
SETPOINT_MAX_GAP = 0.5  # s: ...and the last one this recent
FENCE_POLYGON_BIT = 4
FENCE_ACTION_RTL = 1
GCS_HEARTBEAT, GCS_HEARTBEAT_RSSI, GCS_HEARTBEAT_AUTO = 1, 2, 3  # FS_GCS_ENABL
LONG_RTL, LONG_GLIDE, LONG_PARACHUTE, LONG_AUTO = 1, 2, 3, 4  # FS_LONG_ACTN
SHORT_DISABLED = 3  # FS_SHORT_ACTN
ITEM_NAMES = {  # ArduPilot's short names of mission commands ("Mission: 1 LoitUnlim")
    mavlink.MAV_CMD_NAV_WAYPOINT: "WP",
    mavlink.MAV_CMD_NAV_LOITER_UNLIM: "LoitUnlim",
    mavlink.MAV_CMD_NAV_LOITER_TURNS: "LoitTurns",
    mavlink.MAV_CMD_NAV_LOITER_TIME: "LoitTime",
    mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH: "RTL",
}
PX4_OFFBOARD_LOSS = {0: "POSCTL", 1: "ALTCTL", 2: "MANUAL", 3: "AUTO.RTL"}  # COM_OBL_RC_ACT; else Hold
PX4_GEOFENCE_WARN, PX4_GEOFENCE_RETURN = 1, 3  # GF_ACTION


class Vehicle:
    """Arming, flight mode, guidance target, fence and failsafes of one vehicle."""

    def __init__(
        self, index: int, flavour: Flavour, params: ParamStore, home: tuple[float, float],
        alt: float, step: float,
    ) -> None:
        self.index, self.sysid = index, index + 1
        self.flavour, self.params = flavour, params
        self._nav = (flavour.nav_period, flavour.nav_damping)
        self.home = home
        self.last_xy, self.last_heading = home, 0.0
        self.step = step
        self.armed = False
        self.mode: Mode = flavour.by_name(flavour.initial)
        self.nav: Nav = None
        self.guided_point = Loiter(home[0], home[1], self.loiter_radius)
        self.speed = params.value("cruise_speed")
        self.alt_target = alt
        self.mission: list[Waypoint] = []
        self.mission_index = 0
        self.fence = Fence()  # its inclusion and exclusion zones, local frame
        self.fence_breached = False
        self.setpoints: deque[float] = deque(maxlen=3)
        self.offboard_nav: Nav = None
        self.texts: list[tuple[int, str]] = []  # STATUSTEXTs to send (severity, text)
        self.gcs_heard = 0.0  # simulated time of the latest HEARTBEAT from MAV_GCS_SYSID (boot counts)
        self.gcs_failsafe = False
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
    def roll_limit(self) -> float:
        return math.radians(self.params.value("roll_limit"))

    @property
    def px4(self) -> bool:
        return self.flavour.name == "px4"

    @property
    def fence_enabled(self) -> bool:
        p = self.params
        if self.px4:
            return bool(self.fence.zones) and p.value("geofence_action") != 0
        return bool(self.fence.zones) and p.value("fence_enable", 0.0) == 1 and (
            int(p.value("fence_type", 0.0)) & FENCE_POLYGON_BIT > 0
        )

    @property
    def current_seq(self) -> int:
        if self.mission and self.mission_index < len(self.mission):
            return self.mission[self.mission_index].seq
        return 0

    def say(self, text: str, severity: int = mavlink.MAV_SEVERITY_INFO) -> None:
        self.texts.append((severity, text))

    def heartbeat(self, t: float, sysid: int) -> None:
        """A HEARTBEAT from system `sysid` arrived at simulated time `t`."""
        if sysid == int(self.params.value("gcs_sysid", 0.0)):
            self.gcs_heard = t

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
        """MAV_CMD_DO_REPOSITION: fly to `target` and circle it.

        MAV_CMD_DO_REPOSITION: fly to `target` and circle it (ArduPlane GUIDED: `radius` 0 means
        WP_LOITER_RAD, its sign the direction; PX4 Hold: at NAV_LOITER_RAD clockwise, and without the
        change-mode flag UNSUPPORTED, yet flown when in Hold)."""
        go_to = self.flavour.by_name(self.flavour.reposition)
        refused = mavlink.MAV_RESULT_UNSUPPORTED if self.px4 else mavlink.MAV_RESULT_FAILED
        result = mavlink.MAV_RESULT_ACCEPTED if change_mode or not self.px4 else refused
        if self.mode != go_to and not change_mode:
            return refused
        if self.mode != go_to:
            self._enter(go_to, x, y)
        radius = self.loiter_radius if self.px4 or not radius else radius
        self.guided_point = Loiter(target[0], target[1], radius)
        self.nav = self.guided_point
        if up is not None:
            self.alt_target = up
        return result

    def change_heading(self, t: float, x: float, y: float, kind: int, heading: float, accel: float) -> int:
        """MAV_CMD_GUIDED_CHANGE_HEADING (ArduPlane): hold a heading, or cancel the hold.

        MAV_CMD_GUIDED_CHANGE_HEADING (ArduPlane): hold a heading with at most `accel` m/s^2
        (kinds 0 and 1), or cancel it (kind 2: circle the guided point)."""
        if self.mode.behaviour is not Behaviour.GUIDED:
            return mavlink.MAV_RESULT_FAILED
        self.nav = self.guided_point if kind == 2 else HeadingHold(heading, accel)
        return mavlink.MAV_RESULT_ACCEPTED

    def change_altitude(self, up: float) -> int:
        """MAV_CMD_GUIDED_CHANGE_ALTITUDE (ArduPlane GUIDED): climb or descend to `up`."""
        if self.mode.behaviour is not Behaviour.GUIDED:
            return mavlink.MAV_RESULT_FAILED
        self.alt_target = up
        return mavlink.MAV_RESULT_ACCEPTED

    def change_speed(self, speed: float) -> int:
        """DO_CHANGE_SPEED / GUIDED_CHANGE_SPEED: new cruise speed (negative: no change)."""
        if speed < 0:
            return mavlink.MAV_RESULT_ACCEPTED
        p = self.params
        if p.grid or not p.value("airspeed_min") <= speed <= p.value("airspeed_max"):
            return mavlink.MAV_RESULT_DENIED
        self.speed = speed
        return mavlink.MAV_RESULT_ACCEPTED

    def set_param(self, index: int, value: float) -> bool:
        ok = self.params.set(index, value)
        if ok and self.params.specs[index].key == "cruise_speed":
            self.speed = value
        return ok

    def set_fence(self, fence: Fence) -> None:
        """The fence uploaded (PX4 drops each zone that keeps out home or the vehicle, and says so)."""
        if self.px4:
            kept, points = [], (("Home position", self.home), ("current vehicle position", self.last_xy))
            for zone in fence.zones:
                for where, point in points:
                    if zone.keeps_out(*point):
                        self.say(f"Geofence invalid, doesn't contain {where}", mavlink.MAV_SEVERITY_WARNING)
                        break
                else:
                    kept.append(zone)
            fence = Fence(tuple(kept))
        self.fence, self.fence_breached = fence, False

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
                if not (isinstance(old, Loiter) and (old.x, old.y) == target):
                    self.offboard_nav = Loiter(target[0], target[1], self._orbit_radius(target))
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
    def steer(self, t: float, x: float, y: float, heading: float) -> Turn:
        """Apply the fence and failsafes, then the turn the current guidance asks for."""
        self.last_xy, self.last_heading = (x, y), heading
        self._fence_check(x, y)
        self._failsafes(t, x, y)
        v = max(self.speed, 1.0)
        target = self.nav
        if target is None:
            return Turn()
        if isinstance(target, RateHold):
            return Turn(bank=None, rate=target.rate)
        if isinstance(target, HeadingHold):
            bank = nav.heading_hold(heading, target.heading, target.accel)
            return Turn(bank, limit=nav.heading_bank_limit(target.accel))
        if isinstance(target, Leg):
            self._check_arrival(target, x, y, heading)
            if self.nav is not target:
                return self.steer(t, x, y, heading)
            accel = nav.track(x, y, heading, v, target.start, (target.x, target.y), *self._nav)
        else:
            accel = nav.loiter(x, y, heading, v, (target.x, target.y), target.radius, *self._nav)
        return Turn(math.atan(accel / nav.GRAVITY))

    def _check_arrival(self, leg: Leg, x: float, y: float, heading: float) -> None:
        radius = self.params.value("wp_radius")
        dx, dy = leg.x - x, leg.y - y
        d = math.hypot(dx, dy)
        behind = dx * math.cos(heading) + dy * math.sin(heading) < 0
        if d > radius and not (behind and d < 3 * radius):
            return
        leg.arrived = True
        if self.mode.behaviour is Behaviour.AUTO and self.mission_index < len(self.mission):
            wp = self.mission[self.mission_index]
            self.reached.append(wp.seq)
            self.say(f"Reached waypoint #{wp.seq}")
            self.mission_index += 1
            self._next_waypoint()

    def _fence_check(self, x: float, y: float) -> None:
        if not self.fence_enabled:
            self.fence_breached = False
            return
        outside = self.fence.breached(x, y)
        if outside and not self.fence_breached and self.armed:
            self.say("Geofence violation" if self.px4 else "Fence breached", mavlink.MAV_SEVERITY_CRITICAL)
            self._fence_action(x, y)
        self.fence_breached = outside

    def _fence_action(self, x: float, y: float) -> None:
        rtl = self.flavour.by_name(self.flavour.rtl)
        if not self.px4:
            if self.params.value("fence_action", 0.0) == FENCE_ACTION_RTL and self.mode != rtl:
                self._enter(rtl, x, y)
            return
        action = self.params.value("geofence_action")
        if action == PX4_GEOFENCE_RETURN:
            self._enter(rtl, x, y)
        elif action > PX4_GEOFENCE_WARN:  # Hold where it is (also for termination and landing)
            self._enter(self.flavour.by_name(self.flavour.hold), x, y, again=True)

    def _failsafes(self, t: float, x: float, y: float) -> None:
        self._gcs_failsafe(t, x, y)
        if self.mode.behaviour is Behaviour.GUIDED and isinstance(self.nav, RateHold):
            if t > self.nav.expires:
                self.nav = self.guided_point
        elif self.mode.behaviour is Behaviour.OFFBOARD and (
            not self.setpoints or t - self.setpoints[-1] > self.params.value("guided_timeout")
        ):
            action = int(self.params.value("offboard_loss_action", 5.0))
            to = self.flavour.by_name(PX4_OFFBOARD_LOSS.get(action, self.flavour.hold))
            self._enter(to, x, y)
            self.say(f"Offboard setpoints lost: {to.name}", mavlink.MAV_SEVERITY_WARNING)

    @property
    def _watching_gcs(self) -> bool:
        """Whether the GCS failsafe is armed and has not fired: it counts the GCS's silence."""
        enabled = int(self.params.value("gcs_failsafe", 0.0))
        watching = enabled in (GCS_HEARTBEAT, GCS_HEARTBEAT_RSSI) or (
            enabled == GCS_HEARTBEAT_AUTO and self.mode.behaviour is Behaviour.AUTO
        )
        return watching and self.armed and not self.gcs_failsafe

    def awaits_gcs(self, t: float, quiet: float) -> bool:
        """Whether the armed GCS failsafe has not heard its ground station for over `quiet` s.

        Whether the GCS failsafe, not fired, has heard nothing from its ground station for more
        than `quiet` seconds at time `t` (the simulator's clock then runs at real time: `pace`)."""
        return t - self.gcs_heard > quiet and self._watching_gcs

    def _gcs_failsafe(self, t: float, x: float, y: float) -> None:
        p = self.params
        silent = t - self.gcs_heard
        if self.gcs_failsafe:
            short = p.value("short_action", 0.0) != SHORT_DISABLED
            if silent < p.value("short_timeout" if short else "long_timeout", math.inf):
                self.gcs_failsafe = False
                self.say("GCS Failsafe Cleared", mavlink.MAV_SEVERITY_WARNING)
            return
        if self._watching_gcs and silent > p.value("long_timeout"):
            self.gcs_failsafe = True
            target = self._long_failsafe_mode(int(p.value("long_action")))
            if target is not None:
                self.set_mode(self.flavour.by_name(target).custom_mode, t, x, y)
            self.say(f"GCS Failsafe On: {self.mode.name}", mavlink.MAV_SEVERITY_WARNING)

    def _long_failsafe_mode(self, action: int) -> str | None:
        """The mode ArduPlane's long failsafe switches to from the current mode (None: stay)."""
        if self.mode.behaviour in (Behaviour.GUIDED, Behaviour.AUTO):
            return {LONG_RTL: "RTL", LONG_GLIDE: "FBWA", LONG_AUTO: "AUTO"}.get(action)
        if self.mode.behaviour is Behaviour.RTL:
            return "AUTO" if action == LONG_AUTO else None
        if action == LONG_PARACHUTE:
            return None
        return {LONG_GLIDE: "FBWA", LONG_AUTO: "AUTO"}.get(action, "RTL")

    # ---- internals ----------------------------------------------------------------------
    def _stream_ok(self, t: float) -> bool:
        s = self.setpoints
        return (
            len(s) == s.maxlen and t - s[0] <= SETPOINT_RATE_WINDOW and t - s[-1] <= SETPOINT_MAX_GAP
        )

    def _orbit_radius(self, target: tuple[float, float]) -> float:
        """The signed radius PX4 orbits an OFFBOARD position setpoint at.

        PX4 orbits an OFFBOARD position setpoint at its tightest turn, v^2 / (g tan(FW_R_LIM)), on
        the side the point now lies (counter-clockwise: negative)."""
        radius = max(self.speed, 1.0) ** 2 / (nav.GRAVITY * math.tan(self.roll_limit))
        x, y = self.last_xy
        h = self.last_heading
        left = math.cos(h) * (target[1] - y) - math.sin(h) * (target[0] - x) > 0
        return -radius if left else radius

    def _enter(self, mode: Mode, x: float, y: float, again: bool = False) -> None:
        """Enter `mode` at (x, y) (`again`: also if already in it, from here)."""
        if mode == self.mode and not again:
            return
        self.mode, self.last_xy = mode, (x, y)
        b = mode.behaviour
        if b is Behaviour.STRAIGHT:
            self.nav = None
        elif b is Behaviour.GUIDED:
            self.guided_point = Loiter(x, y, self.loiter_radius)
            self.nav = self.guided_point
        elif b is Behaviour.LOITER:
            self.nav = Loiter(x, y, self.loiter_radius)
        elif b is Behaviour.RTL:
            self.nav = Loiter(self.home[0], self.home[1], self.loiter_radius)
            self.alt_target = self._return_altitude()
        elif b is Behaviour.OFFBOARD:
            self.nav = self.offboard_nav or Loiter(x, y, self.loiter_radius)
        else:
            self._next_waypoint()

    def _return_altitude(self) -> float:
        """The altitude a return flies at.

        The altitude a return flies at: ArduPlane's RTL_ALTITUDE (-1: the altitude it has), PX4's
        RTL_RETURN_ALT or higher (an aircraft above it returns at its own; the simulator then circles
        home there, without PX4's descent to RTL_DESCEND_ALT)."""
        rtl = self.params.value("rtl_altitude", -1.0)
        if self.px4:
            return max(self.alt_target, rtl)
        return rtl if rtl >= 0 else self.alt_target

    def _next_waypoint(self) -> None:
        """Point the AUTO guidance at the current mission item, ending the mission when done."""
        while self.mission_index < len(self.mission):
            wp = self.mission[self.mission_index]
            if wp.command == mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH:
                self.say(f"Mission: {wp.seq} RTL")
                self._enter(self.flavour.by_name(self.flavour.rtl), *self.last_xy)
                return
            if wp.here or math.isfinite(wp.x):
                x, y = self.last_xy if wp.here else (wp.x, wp.y)
                self.say(f"Mission: {wp.seq} {ITEM_NAMES.get(wp.command, 'Cmd')}")
                if wp.command == mavlink.MAV_CMD_NAV_LOITER_UNLIM:
                    self.nav = Loiter(x, y, wp.radius or self.loiter_radius)
                else:
                    self.nav = Leg(self.last_xy, x, y)
                if wp.up is not None:
                    self.alt_target = wp.up
                return
            self.mission_index += 1
        self.say("Mission complete")
        self._enter(self.flavour.by_name(self.flavour.mission_end), *self.last_xy)
