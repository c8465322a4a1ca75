"""The phases an altitude-bench flight flies on ArduPilot (and the bundled simulator) and on PX4.

Each phase starts with the vehicle settled at its layer (`settle`) and is recorded in the
`Flight` with its vehicle times (docs/companion.md, "Altitude keeping").
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Sequence

from companion.bench.altitude_figures import BenchError, Flight, Phase
from companion.contracts.frames import LocalFrame
from companion.contracts.mission import Mission
from companion.core.agent import Command
from companion.core.kinematics import wrap_angle
from companion.core.trajectory import Trajectory
from companion.core.world import World, build_world
from companion.node.failsafe import FailsafeLoiter, arm_failsafe, hand_over
from companion.node.guidance import Guidance
from companion.node.takeover import take_over
from companion.node.vehicle_link import (
    ARDUPILOT_AUTO,
    ARDUPILOT_GUIDED,
    COMPANION_SYSTEM,
    PX4_HOLD,
    VehicleLink,
)

ARDUPILOT_PHASES = ("guided-turn", "failsafe-loiter", "hand-over", "layer-change")
TURN_STEPS = 12  # steps at the turn limit one way, then the other
STRAIGHT = 10**6  # Turns(level=STRAIGHT) flies straight on
HAND_OVER_TURNS = 3  # steps at the turn limit before a hand-over or failsafe
LEVEL_SETTLED_M = 0.5  # ArduPilot phases start wings level within this of the layer
LOITER_S = 80.0  # vehicle seconds a loiter phase is measured for (more than one circle)
LAYER_CHANGE_M = 40.0
SETTLED_M, SETTLED_RATE, SETTLED_S, SETTLE_TIMEOUT_S = 3.0, 0.5, 8.0, 150.0
REACHED_M = 2.0  # a layer change is done this close to its target
WALL_TIMEOUT_S = 240.0  # wall seconds any one wait may take
CENTRE = (0.0, -300.0)  # where a vehicle settles: south of the region's centre


def wait(
    link: VehicleLink, until: Callable[[], bool], what: str, each: Callable[[], None] = lambda: None
) -> None:
    """Poll `link` (doing `each` after every poll) until `until()`; BenchError after WALL_TIMEOUT_S."""
    deadline = time.monotonic() + WALL_TIMEOUT_S
    while not until():
        if time.monotonic() > deadline:
            raise BenchError(f"{what}: not within {WALL_TIMEOUT_S:.0f} s")
        link.poll(0.02)
        each()


def fly_for(link: VehicleLink, seconds: float, each: Callable[[], None] = lambda: None) -> None:
    end = link.state.time_s + seconds
    wait(link, lambda: link.state.time_s >= end, f"{seconds:.0f} s of flight", each)


def settle(
    link: VehicleLink,
    frame: LocalFrame,
    altitude: float,
    reposition: bool = True,
    tolerance: float = SETTLED_M,
    each: Callable[[], None] = lambda: None,
) -> None:
    """Fly until settled at `altitude`.

    Fly to CENTRE at `altitude` and circle there (or, without `reposition`, fly on as `each`
    steers) until settled at it (SETTLED_S within `tolerance`, slower than SETTLED_RATE)."""
    s = link.state
    if reposition:
        lat, lon, _ = frame.to_geodetic(*CENTRE)
        link.commands.reposition(lat, lon, altitude)
    since = [math.inf]
    last_climb = [0.0]
    prev = [(s.time_s, s.up)]

    def check() -> None:
        t, up = s.time_s, s.up
        if t > prev[0][0] + 1.0:  # the rate over a second: GLOBAL_POSITION_INT is noisy
            last_climb[0] = (up - prev[0][1]) / (t - prev[0][0])
            prev[0] = (t, up)
        each()
        ok = abs(up - altitude) < tolerance and abs(last_climb[0]) < SETTLED_RATE
        since[0] = min(since[0], t) if ok else math.inf

    end = s.time_s + SETTLE_TIMEOUT_S
    wait(link, lambda: s.time_s - since[0] >= SETTLED_S or s.time_s > end, "settling", check)
    if s.time_s > end:
        raise BenchError(f"not settled at {altitude:.0f} m in {SETTLE_TIMEOUT_S:.0f} s (at {s.up:.1f} m)")


class Turns:
    """The companion's guidance turning at the turn limit, one way then the other.

    The companion's guidance: `level` steps straight on (wings level), then turning at the turn
    limit, TURN_STEPS steps one way, then the other."""

    def __init__(self, guidance: Guidance, mission: Mission, level: int = 0) -> None:
        self.guidance, self.k, self.level = guidance, mission.kinematics, level
        self.count, self.next_step = 0, -math.inf
        self.straight = math.nan  # the heading flown while level

    def __call__(self) -> None:
        s, g = self.guidance.link.state, self.guidance
        if s.time_s >= self.next_step:
            turning = self.count - self.level
            side = 0.0 if turning < 0 else 1.0 if (turning // TURN_STEPS) % 2 == 0 else -1.0
            turn = side * math.radians(self.k.turn_limit_deg)
            if not math.isfinite(self.straight):
                self.straight = s.heading
            heading = float(wrap_angle(s.heading + turn)) if turning >= 0 else self.straight
            cmd = Command(
                step=self.count,
                turn=turn,
                heading_rate=turn / self.k.step,
                heading=heading,
                waypoint=(s.x, s.y),
                path=(),
            )
            g.step(cmd, (s.x, s.y))
            self.count += 1
            self.next_step = s.time_s + self.k.step
        elif g.due(s.time_s):
            g.repeat()


def record_phase(
    flight: Flight, link: VehicleLink, name: str, target: float, body: Callable[[], None], errors: bool = True
) -> None:
    start = link.state.time_s
    body()
    flight.phases.append(Phase(name, start, link.state.time_s, target, errors))
    print(
        f"  {flight.autopilot}: {name} flown from {start:.0f} to {link.state.time_s:.0f} s of vehicle time",
        flush=True,
    )


def committed(link: VehicleLink, uav: int, mission: Mission) -> Trajectory:
    """A trajectory in force anchored at the pose: straight on for the horizon, then a clockwise loiter."""
    s = link.state
    return Trajectory(0, s.x, s.y, s.heading, (0.0,) * mission.algorithm.horizon, -1)


ARDUPILOT_PARAMS = [
    "TECS_CLMB_MAX",
    "TECS_SINK_MIN",
    "TECS_SINK_MAX",
    "TECS_RLL2THR",
    "TECS_TIME_CONST",
    "ALT_HOLD_RTL",
    "RTL_ALTITUDE",
    "ROLL_LIMIT_DEG",
    "AIRSPEED_CRUISE",
]
PX4_PARAMS = [
    "FW_T_CLMB_MAX",
    "FW_T_SINK_MIN",
    "FW_T_SINK_MAX",
    "FW_T_CLMB_R_SP",
    "FW_T_SINK_R_SP",
    "FW_T_ALT_TC",
    "FW_R_LIM",
    "RTL_RETURN_ALT",
    "COM_OBL_RC_ACT",
    "COM_OF_LOSS_T",
]


def guided(link: VehicleLink) -> None:
    wait(
        link,
        lambda: link.state.custom_mode == ARDUPILOT_GUIDED,
        "GUIDED",
        every(1.0, lambda: link.commands.set_mode(ARDUPILOT_GUIDED)),
    )


def every(period: float, act: Callable[[], None]) -> Callable[[], None]:
    last = [-math.inf]

    def each() -> None:
        if time.monotonic() - last[0] >= period:
            act()
            last[0] = time.monotonic()

    return each


def reached(link: VehicleLink, target: float) -> Callable[[], bool]:
    """Whether the vehicle is within REACHED_M of the altitude `target` (m above home)."""
    return lambda: abs(link.state.up - target) < REACHED_M


def fly_ardupilot(
    flight: Flight,
    link: VehicleLink,
    companion_url: str,
    mission: Mission,
    uav: int,
    phases: Sequence[str] = ARDUPILOT_PHASES,
    loiter_s: float = LOITER_S,
) -> None:
    """The ArduPilot phases on an airborne vehicle in GUIDED.

    The ArduPilot phases on an airborne vehicle in GUIDED (`link`: the observer; `companion_url`
    a second link to it, for the companion whose silence fires the failsafe)."""
    frame, layer = link.frame, mission.altitude_of(uav)
    world = build_world(mission)
    flight.params = link.params.read(ARDUPILOT_PARAMS)
    if "guided-turn" in phases:
        guided(link)
        settle(link, frame, layer)
        guidance = Guidance(link, frame, mission, uav, "heading")
        settle(link, frame, layer, False, LEVEL_SETTLED_M, Turns(guidance, mission, STRAIGHT))
        turns = Turns(guidance, mission)
        record_phase(
            flight,
            link,
            "guided-turn",
            layer,
            lambda: fly_for(link, 2 * TURN_STEPS * mission.kinematics.step, turns),
        )
    if "failsafe-loiter" in phases:
        guided(link)
        settle(link, frame, layer)
        companion = VehicleLink(companion_url, frame, system=COMPANION_SYSTEM, heartbeat=True)
        try:
            _failsafe(flight, link, companion, mission, uav, world)
        finally:
            companion.close()
        link.params.set("FS_GCS_ENABL", 0.0)
    if "hand-over" in phases:
        guided(link)
        settle(link, frame, layer)
        guidance = Guidance(link, frame, mission, uav, "heading")
        settle(link, frame, layer, False, LEVEL_SETTLED_M, Turns(guidance, mission, STRAIGHT))
        fly_for(link, HAND_OVER_TURNS * mission.kinematics.step, Turns(guidance, mission))  # turning hard
        loiter = FailsafeLoiter(link, world, uav, frame)

        def handed() -> None:
            error = hand_over(loiter, committed(link, uav, mission), threading.Event())
            if error:
                raise BenchError(f"hand-over: {error}")
            fly_for(link, loiter_s)

        record_phase(flight, link, "hand-over", layer, handed)
    if "layer-change" in phases:
        guided(link)
        settle(link, frame, layer)

        def change() -> None:
            for target in (layer + LAYER_CHANGE_M, layer):
                link.commands.change_altitude(target)
                wait(link, reached(link, target), f"layer change to {target:.0f} m")
            fly_for(link, 5.0)

        record_phase(flight, link, "layer-change", layer, change, errors=False)


def _failsafe(
    flight: Flight, link: VehicleLink, companion: VehicleLink, mission: Mission, uav: int, world: World
) -> None:
    companion.wait_heartbeat(30)
    companion.request_streams()
    wait(companion, lambda: companion.state.has_pose, "the companion link's pose")
    loiter = FailsafeLoiter(companion, world, uav, link.frame)
    guidance = Guidance(companion, link.frame, mission, uav, "heading")
    turns = Turns(guidance, mission, STRAIGHT)
    step_at = [companion.state.time_s]
    armed = [False]

    def follow() -> None:
        link.poll(0.0)
        turns()
        if armed[0] and companion.state.time_s - step_at[0] >= mission.kinematics.step:
            loiter.follow(committed(companion, uav, mission))
            step_at[0] = companion.state.time_s

    settle(companion, link.frame, mission.altitude_of(uav), False, LEVEL_SETTLED_M, follow)
    error = arm_failsafe(loiter, committed(companion, uav, mission))
    if error:
        raise BenchError(f"arming the failsafe: {error}")
    armed[0] = True
    turns = Turns(guidance, mission)
    fly_for(companion, HAND_OVER_TURNS * mission.kinematics.step, follow)
    if link.state.custom_mode != ARDUPILOT_GUIDED:
        raise BenchError(f"failsafe: fired before the silence (mode {link.state.custom_mode})")
    companion.poll(0.0)
    companion.send_heartbeat()
    companion.close()  # the companion dies

    def silent() -> None:
        fly_for(link, LOITER_S)
        if link.state.custom_mode != ARDUPILOT_AUTO:
            raise BenchError(f"failsafe: not in AUTO after the silence (mode {link.state.custom_mode})")

    record_phase(flight, link, "failsafe-loiter", mission.altitude_of(uav), silent)


def fly_px4(flight: Flight, link: VehicleLink, mission: Mission, uav: int) -> None:
    """The PX4 phases on an airborne vehicle (`link`: the companion's link, also the observer)."""
    frame, layer = link.frame, mission.altitude_of(uav)
    k = mission.kinematics
    stop = threading.Event()
    settle(link, frame, layer)
    guidance = Guidance(link, frame, mission, uav, "position-target")
    if not (take_over(link, guidance, uav, stop) or take_over(link, guidance, uav, stop)):
        raise BenchError("OFFBOARD not taken (twice)")
    turns = Turns(guidance, mission)
    record_phase(flight, link, "offboard", layer, lambda: fly_for(link, 2 * TURN_STEPS * k.step, turns))

    def hold() -> None:
        wait(
            link,
            lambda: link.state.custom_mode == PX4_HOLD,
            "Hold",
            every(1.0, lambda: link.commands.set_mode(PX4_HOLD)),
        )
        fly_for(link, LOITER_S)

    record_phase(flight, link, "hold", layer, hold)
    settle(link, frame, layer, reposition=False)
    guidance = Guidance(link, frame, mission, uav, "position-target")
    if not (take_over(link, guidance, uav, stop) or take_over(link, guidance, uav, stop)):
        raise BenchError("OFFBOARD not taken again (twice)")
    turns = Turns(guidance, mission)
    fly_for(link, 3 * k.step, turns)

    def lost() -> None:  # no setpoint from now on
        fly_for(link, LOITER_S)
        if link.state.custom_mode != PX4_HOLD:
            raise BenchError(f"offboard loss: not in Hold (mode {link.state.custom_mode:#x})")

    record_phase(flight, link, "offboard-loss", layer, lost)
    flight.params = link.params.read(PX4_PARAMS)  # as the companion's take-over left them

