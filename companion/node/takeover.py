"""`--takeover`: put the vehicle into its guided mode, armed, and airborne if it is on the ground.

Without `--takeover` the companion never arms the vehicle or changes its mode. With it:

- a vehicle disarmed on the ground (below `ON_GROUND_M`) takes off, arming retried, and climbs
  until it has levelled off at its layer (`Levelling`): ArduPilot by TKOFF_ALT and mode TAKEOFF; PX4 by
  MAV_CMD_NAV_TAKEOFF (AUTO.TAKEOFF) once its altitude reference reached the ground (`px4_ready_at`);
- PX4 OFFBOARD: the OFFBOARD-loss failsafe becomes Hold if it was a stick-flown mode;
- then the guided mode (ArduPilot GUIDED; PX4 OFFBOARD, or Hold for `reposition`) and arming,
  retried every second until the HEARTBEAT shows both; for OFFBOARD (PX4 needs a setpoint stream)
  a point ahead on the current heading streams first, and on until the first step replaces it.
Each step in detail, and why: docs/companion.md, "--takeover".
"""

from __future__ import annotations

import logging
import math
import threading
import time

from companion.contracts.mission import ALTITUDE_KEEPING
from companion.node.guidance import STREAM_PERIOD_S, Guidance
from companion.node.vehicle_link import (
    ARDUPILOT_GUIDED,
    ARDUPILOT_TAKEOFF,
    PX4_HOLD,
    PX4_OFFBOARD,
    PX4_TAKEOFF,
    VehicleLink,
)

log = logging.getLogger("companion")

TAKEOVER_TIMEOUT_S = 30.0  # wall seconds to get the guided mode and arming once airborne
TAKEOFF_TIMEOUT_S = 300.0  # wall seconds for a take-off (GPS, EKF and pre-arm checks first)
ON_GROUND_M = 10.0
PX4_REFERENCE_RATE = "FW_T_CLMB_R_SP"  # m/s: how fast PX4's altitude reference climbs before take-off
PX4_REFERENCE_MARGIN_S = 5.0
OFFBOARD_LOSS, OFFBOARD_LOSS_MANUAL, OFFBOARD_LOSS_HOLD = "COM_OBL_RC_ACT", 2, 5
LEVEL_M = 1.0  # m below the layer at which a climb counts as levelled off
LEVEL_GAIN_M, LEVEL_S = 0.5, 5.0  # or: no more gain than this over these vehicle seconds, within 5 m
SETTLE_S = 10.0  # vehicle seconds of the autopilot's own level flight before the companion steers


def guided_mode(link: VehicleLink, command_mode: str) -> int:
    """The custom mode the companion steers in."""
    if link.state.px4:
        return PX4_HOLD if command_mode == "reposition" else PX4_OFFBOARD
    return ARDUPILOT_GUIDED


def steerable(link: VehicleLink, command_mode: str) -> bool:
    """Whether the vehicle is in a mode the companion may steer in."""
    s = link.state
    if s.px4 and command_mode == "reposition":
        return s.custom_mode in (PX4_HOLD, PX4_OFFBOARD)
    return s.custom_mode == guided_mode(link, command_mode)


def take_over(link: VehicleLink, guidance: Guidance, uav: int, stop: threading.Event) -> bool:
    """Airborne (if needed), guided and armed; False if it did not happen in time."""
    s = link.state
    if not s.armed and s.up < ON_GROUND_M:
        lift = take_off_px4 if s.px4 else take_off
        if not lift(link, guidance.altitude, uav, stop):
            return False
    mode = guidance.mode
    want = guided_mode(link, mode)
    offboard = want == PX4_OFFBOARD
    if offboard:
        hold_on_offboard_loss(link, uav)
    deadline = time.monotonic() + TAKEOVER_TIMEOUT_S
    sent, last_wall, last_try = 0, -math.inf, -math.inf
    while not stop.is_set() and not (steerable(link, mode) and s.armed):
        now = time.monotonic()
        if now > deadline:
            log.warning("uav %d: takeover failed: not in the guided mode and armed", uav)
            return False
        period = STREAM_PERIOD_S["position-target"]
        if offboard and (s.time_s - guidance.last_send >= period or now - last_wall >= period):
            guidance.hold_course(s.x, s.y, s.heading)
            last_wall, sent = now, sent + 1
        if (not offboard or sent >= 3) and now - last_try >= 1.0:
            link.commands.set_mode(want)
            link.commands.arm()
            last_try = now
        link.poll(0.02)
    return not stop.is_set()


def hold_on_offboard_loss(link: VehicleLink, uav: int) -> None:
    """PX4: make the OFFBOARD-loss failsafe Hold (COM_OBL_RC_ACT 5) where it is a stick-flown mode.

    The stick-flown modes are Position, Altitude and Manual (0-2): without sticks a fixed-wing flies
    straight on in them.
    """
    action = link.params.read([OFFBOARD_LOSS]).get(OFFBOARD_LOSS)
    if action is not None and action <= OFFBOARD_LOSS_MANUAL:
        link.params.set(OFFBOARD_LOSS, OFFBOARD_LOSS_HOLD)
        log.info(
            "uav %d: %s was %d; set to Hold (5): the vehicle circles if the companion stops",
            uav,
            OFFBOARD_LOSS,
            action,
        )


def take_off(link: VehicleLink, altitude: float, uav: int, stop: threading.Event) -> bool:
    """ArduPilot: TAKEOFF mode to `altitude` metres above home; True once it has climbed."""
    s = link.state
    log.info("uav %d: on the ground: taking off to %.0f m", uav, altitude)
    if not link.params.set("TKOFF_ALT", altitude):
        log.warning("uav %d: TKOFF_ALT not confirmed; taking off anyway", uav)
    deadline = time.monotonic() + TAKEOFF_TIMEOUT_S
    last_try = -math.inf
    while not stop.is_set() and not (s.armed and s.custom_mode == ARDUPILOT_TAKEOFF):
        if time.monotonic() > deadline:
            log.warning("uav %d: take-off failed: GPS fix %d, pre-arm checks %s", uav, s.gps_fix, s.prearm_ok)
            return False
        if s.gps_fix >= 3 and s.prearm_ok and time.monotonic() - last_try >= 1.0:
            link.commands.set_mode(ARDUPILOT_TAKEOFF)
            link.commands.arm()
            last_try = time.monotonic()
        link.poll(0.1)
    return climb(link, altitude, uav, stop, deadline)


def climb(link: VehicleLink, altitude: float, uav: int, stop: threading.Event, deadline: float) -> bool:
    """Wait until the vehicle has levelled off at its layer and flown on level (`Levelling`).

    False if not in time. A companion that steered from lower down could fly its plans, which keep
    apart only the UAVs of a layer, through the layers below its own; one that steered as soon as
    the climb ended would see the aircraft sink as it trades height for cruise speed (PX4 SIH:
    4-7 m below the layer in the first steps after hand-overs at 1-5 m below it; after `SETTLE_S`
    of the autopilot's own level flight, 2.1-2.8 m at most over the runs measured)."""
    s = link.state
    level = Levelling(altitude)
    while not stop.is_set() and not level.reached(s.time_s, s.up):
        if time.monotonic() > deadline or not s.armed:
            log.warning("uav %d: take-off failed at %.0f m (armed %s)", uav, s.up, s.armed)
            return False
        link.poll(0.1)
    log.info("uav %d: airborne at %.1f m (layer %.0f m)", uav, s.up, altitude)
    return not stop.is_set()


class Levelling:
    """Whether a climbing aircraft has levelled off at `altitude` and flown on level since.

    Levelled: within `LEVEL_M` of `altitude`, or within `ALTITUDE_KEEPING` and gaining no more than
    `LEVEL_GAIN_M` over `LEVEL_S` of vehicle time (an autopilot that holds its take-off altitude a
    little low). Then `SETTLE_S` of vehicle time more, still within `ALTITUDE_KEEPING`: the
    autopilot's own level flight brings it to cruise speed. Leaving the band starts over."""

    def __init__(self, altitude: float) -> None:
        self.altitude = altitude
        self.since: tuple[float, float] | None = None  # (vehicle time, altitude) the last gain began
        self.level_at: float | None = None  # the vehicle time it levelled off

    def reached(self, t: float, up: float) -> bool:
        """Feed one position (vehicle time `t`, altitude `up`); True once levelled and settled."""
        if not up >= self.altitude - ALTITUDE_KEEPING:
            self.since = self.level_at = None
            return False
        if self.level_at is None:
            if self.since is None or up > self.since[1] + LEVEL_GAIN_M or t < self.since[0]:
                self.since = (t, up)
            if up >= self.altitude - LEVEL_M or t - self.since[0] >= LEVEL_S:
                self.level_at = t
        return self.level_at is not None and t - self.level_at >= SETTLE_S


def px4_ready_at(home_amsl: float, rate: float) -> float:
    """The vehicle time (s since boot) from which a PX4 fixed-wing may take off.

    PX4 (seen with the SIH fixed-wing of July 2025; PX4 issue 27344) starts the altitude reference
    of its energy controller (TECS) at 0 m AMSL at boot and raises it by FW_T_CLMB_R_SP per second
    while the vehicle waits on the ground; taking off before it has reached the ground makes the
    aircraft dive after the take-off, down to where the reference then is. Harmless when fixed:
    a vehicle booted long enough ago never waits.
    """
    return max(home_amsl, 0.0) / max(rate, 0.1) + PX4_REFERENCE_MARGIN_S


def take_off_px4(link: VehicleLink, altitude: float, uav: int, stop: threading.Event) -> bool:
    """PX4: arm, MAV_CMD_NAV_TAKEOFF to `altitude` above home (AUTO.TAKEOFF); True once it has climbed."""
    s = link.state
    deadline = time.monotonic() + TAKEOFF_TIMEOUT_S
    while not stop.is_set() and not (s.gps_fix >= 3 and math.isfinite(s.home_amsl)):
        if time.monotonic() > deadline:
            log.warning("uav %d: take-off failed: GPS fix %d", uav, s.gps_fix)
            return False
        link.poll(0.1)
    rate = link.params.read([PX4_REFERENCE_RATE]).get(PX4_REFERENCE_RATE, 3.0)
    ready = px4_ready_at(s.home_amsl, rate)
    if s.time_s < ready:
        log.info(
            "uav %d: waiting until PX4's altitude reference reaches the ground (%.0f m AMSL at %.1f m/s): "
            "take-off at %.0f s of vehicle time",
            uav,
            s.home_amsl,
            rate,
            ready,
        )
        deadline += ready - s.time_s  # real time at least
    log.info("uav %d: on the ground: taking off to %.0f m", uav, altitude)
    last_try = -math.inf
    while not stop.is_set() and not (s.armed and s.custom_mode == PX4_TAKEOFF):
        if time.monotonic() > deadline:
            log.warning("uav %d: take-off failed: armed %s, mode %#x", uav, s.armed, s.custom_mode)
            return False
        if s.time_s >= ready and time.monotonic() - last_try >= 1.0:
            last_try = time.monotonic()
            if not s.armed:
                link.commands.arm()
            else:
                link.commands.takeoff(altitude)
        link.poll(0.1)
    return climb(link, altitude, uav, stop, deadline)
