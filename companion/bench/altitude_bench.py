"""Altitude keeping of real autopilots: how far each strays from its layer in every phase the 3D
separation relies on (issue 32; docs/companion.md, "Altitude keeping").

`uavsearch altitude-bench [--autopilot ardupilot-sitl,px4-sitl,bundled] [--out DIR]` (or
`bench_main(argv)`) flies one vehicle of the mission (`--uav I`, its start pose and its layer,
`Mission.altitude_of(I)`) on each autopilot, one after another, through the phases below, and
prints per phase the largest and the 95th percentile of |altitude - layer| and the fastest climb and
sink, from the vehicle's own GLOBAL_POSITION_INT (10 Hz, read back from the observer's .tlog);
`altitude.csv` in `--out` holds the table, `samples.csv` every sample.

ArduPlane SITL (and the bundled simulator, which speaks ArduPilot):
- `guided-turn`: the companion's guidance in `heading` mode (`companion.node.guidance`) flying
  turns at the mission's turn limit, TURN_STEPS steps one way, then the other;
- `failsafe-loiter`: a companion link arms the GCS failsafe (`companion.node.failsafe`) while it
  turns at the turn limit, then falls silent; FS_LONG_TIMEOUT later ArduPlane circles the failsafe
  mission's loiter in AUTO; measured from the silence for LOITER_S;
- `hand-over`: the mission's end (`failsafe.hand_over`) straight out of turns at the turn limit:
  the loiter uploaded and AUTO set at once; measured for LOITER_S;
- `layer-change` (not a phase the guarantee relies on; its climb and sink rates are the autopilot's
  limits, which the bundled simulator copies): GUIDED_CHANGE_ALTITUDE to LAYER_CHANGE_M above the
  layer and back.

PX4 SITL (SIH fixed-wing):
- `offboard`: the companion's guidance in `position-target` mode (OFFBOARD) flying turns at the
  turn limit as above;
- `hold`: Hold (AUTO.LOITER) entered from those turns, for LOITER_S;
- `offboard-loss`: OFFBOARD again, turning, then the setpoint stream stops; PX4's OFFBOARD-loss
  failsafe (COM_OBL_RC_ACT = Hold, as `--takeover` sets it) takes over; measured from the last
  setpoint for LOITER_S.

Every phase starts with the vehicle settled at its layer (within SETTLED_M, climbing or sinking
slower than SETTLED_RATE, for SETTLED_S), an ArduPilot one flying straight and within
LEVEL_SETTLED_M; the figures cover the whole phase, its entry included.
Processes are started and stopped by PID on free loopback ports.
"""

from __future__ import annotations

import argparse
import csv
import math
import shutil
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import msgspec
import numpy as np
from pymavlink import mavutil

from companion.app import px4_sitl, sitl
from companion.app.launcher import Children
from companion.app.loopback import free_blocks
from companion.contracts.arguments import natural, positive, weight
from companion.contracts.frames import LocalFrame
from companion.contracts.mission import Mission
from companion.core.agent import Command
from companion.core.feasibility import load_mission
from companion.core.kinematics import wrap_angle
from companion.core.trajectory import Trajectory
from companion.core.world import build_world
from companion.node.failsafe import FailsafeLoiter, arm_failsafe, hand_over
from companion.node.guidance import Guidance
from companion.node.takeover import take_off, take_off_px4, take_over
from companion.node.vehicle_link import (
    ARDUPILOT_AUTO,
    ARDUPILOT_GUIDED,
    COMPANION_SYSTEM,
    PX4_HOLD,
    VehicleLink,
)

ROOT = Path(__file__).resolve().parents[2]
MISSIONS = {
    "ardupilot-sitl": ROOT / "mission_files" / "scenario1_continuous.toml",
    "px4-sitl": ROOT / "mission_files" / "scenario1_px4.toml",
    "bundled": ROOT / "mission_files" / "scenario1_continuous.toml",
}
SPEEDUPS = {"ardupilot-sitl": 8.0, "px4-sitl": 2.0, "bundled": 8.0}  # PX4 at 4: OFFBOARD lost when busy
GCS_COMPONENT = 190  # MAV_COMP_ID_MISSIONPLANNER: the bench's observer
ARDUPILOT_PHASES = ("guided-turn", "failsafe-loiter", "hand-over", "layer-change")
TURN_STEPS = 12  # steps at the turn limit one way, then the other
STRAIGHT = 10**6  # Turns(level=STRAIGHT) flies straight on
FAILSAFE_TIMEOUT_S = 10.0  # FS_LONG_TIMEOUT flown (vehicle s): 1.25 s of wall time at 8x, as tests/sitl
HAND_OVER_TURNS = 3  # steps at the turn limit before a hand-over or failsafe
LEVEL_SETTLED_M = 0.5  # ArduPilot phases start wings level within this of the layer
LOITER_S = 80.0  # vehicle seconds a loiter phase is measured for (more than one circle)
LAYER_CHANGE_M = 40.0
SETTLED_M, SETTLED_RATE, SETTLED_S, SETTLE_TIMEOUT_S = 3.0, 0.5, 8.0, 150.0
REACHED_M = 2.0  # a layer change is done this close to its target
WALL_TIMEOUT_S = 240.0  # wall seconds any one wait may take
CENTRE = (0.0, -300.0)  # where a vehicle settles: south of the region's centre


@dataclass(frozen=True)
class Phase:
    """A stretch of one flight: vehicle times [start, end) and the altitude it should hold."""

    name: str
    start: float
    end: float
    target: float
    errors: bool = True  # False: only its climb and sink rates mean something (a layer change)


@dataclass(frozen=True)
class Sample:
    """One GLOBAL_POSITION_INT: vehicle time (s), height above home (m), climb rate (m/s, up +)."""

    t: float
    up: float
    climb: float


@dataclass(frozen=True)
class PhaseFigures:
    autopilot: str
    phase: str
    seconds: float
    samples: int
    max_error_m: float  # max |alt - layer|
    p95_error_m: float
    mean_error_m: float  # signed: below the layer is negative
    max_climb_ms: float
    max_sink_ms: float


@dataclass
class Flight:
    """What one autopilot's flight recorded: its phases, the observer's .tlog, the vehicle's system
    id and the autopilot's altitude parameters as read."""

    autopilot: str
    tlog: Path
    system: int = 0
    phases: list[Phase] = field(default_factory=list)
    params: dict[str, float] = field(default_factory=dict)


class BenchError(RuntimeError):
    """A flight could not be done (the message says which step and why)."""


# -- reading the record ------------------------------------------------------------------------------
def read_samples(tlog: Path, system: int) -> list[Sample]:
    """The vehicle's GLOBAL_POSITION_INT in `tlog`, in order."""
    conn = mavutil.mavlink_connection(str(tlog), dialect="ardupilotmega")
    out: list[Sample] = []
    try:
        while (msg := conn.recv_match(type="GLOBAL_POSITION_INT")) is not None:
            if msg.get_srcSystem() == system:
                out.append(Sample(msg.time_boot_ms * 1e-3, msg.relative_alt * 1e-3, -msg.vz * 0.01))
    finally:
        conn.close()
    return out


def figures(autopilot: str, phase: Phase, samples: Sequence[Sample]) -> PhaseFigures:
    """One phase's figures from the samples inside it."""
    inside = [s for s in samples if phase.start <= s.t < phase.end]
    if not inside:
        raise BenchError(
            f"{autopilot} {phase.name}: no GLOBAL_POSITION_INT between {phase.start:.0f} and "
            f"{phase.end:.0f} s"
        )
    err = np.array([s.up - phase.target for s in inside])
    climb = np.array([s.climb for s in inside])
    nan = math.nan
    return PhaseFigures(
        autopilot,
        phase.name,
        phase.end - phase.start,
        len(inside),
        float(np.max(np.abs(err))) if phase.errors else nan,
        float(np.percentile(np.abs(err), 95)) if phase.errors else nan,
        float(np.mean(err)) if phase.errors else nan,
        float(max(np.max(climb), 0.0)) if np.isfinite(climb).all() else nan,
        float(max(-np.min(climb), 0.0)) if np.isfinite(climb).all() else nan,
    )


class Sampler:
    """Samples a link's altitude at every poll (for a link without a .tlog): hook it on `on_poll`.
    Climb rates are not sampled (NaN)."""

    def __init__(self, link: VehicleLink) -> None:
        self.link, self.samples = link, list[Sample]()
        link.on_poll = self

    def __call__(self) -> None:
        s = self.link.state
        if s.has_pose and (not self.samples or s.time_s > self.samples[-1].t):
            self.samples.append(Sample(s.time_s, s.up, math.nan))


def flight_figures(flight: Flight) -> tuple[list[PhaseFigures], list[Sample]]:
    samples = read_samples(flight.tlog, flight.system)
    return [figures(flight.autopilot, p, samples) for p in flight.phases], samples


# -- flying ---------------------------------------------------------------------------------------
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
    """Fly to CENTRE at `altitude` and circle there (or, without `reposition`, fly on as `each`
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
    """The companion's guidance: `level` steps straight on (wings level), then turning at the turn
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


def _phase(
    flight: Flight, link: VehicleLink, name: str, target: float, body: Callable[[], None], errors: bool = True
) -> None:
    start = link.state.time_s
    body()
    flight.phases.append(Phase(name, start, link.state.time_s, target, errors))
    print(
        f"  {flight.autopilot}: {name} flown from {start:.0f} to {link.state.time_s:.0f} s of vehicle time",
        flush=True,
    )


def _committed(link: VehicleLink, uav: int, mission: Mission) -> Trajectory:
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
        _every(1.0, lambda: link.commands.set_mode(ARDUPILOT_GUIDED)),
    )


def _every(period: float, act: Callable[[], None]) -> Callable[[], None]:
    last = [-math.inf]

    def each() -> None:
        if time.monotonic() - last[0] >= period:
            act()
            last[0] = time.monotonic()

    return each


def fly_ardupilot(
    flight: Flight,
    link: VehicleLink,
    companion_url: str,
    mission: Mission,
    uav: int,
    phases: Sequence[str] = ARDUPILOT_PHASES,
    loiter_s: float = LOITER_S,
) -> None:
    """The ArduPilot phases on an airborne vehicle in GUIDED (`link`: the observer; `companion_url`
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
        _phase(
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
            error = hand_over(loiter, _committed(link, uav, mission), threading.Event())
            if error:
                raise BenchError(f"hand-over: {error}")
            fly_for(link, loiter_s)

        _phase(flight, link, "hand-over", layer, handed)
    if "layer-change" in phases:
        guided(link)
        settle(link, frame, layer)

        def change() -> None:
            for target in (layer + LAYER_CHANGE_M, layer):
                link.commands.change_altitude(target)
                wait(
                    link,
                    lambda t=target: abs(link.state.up - t) < REACHED_M,
                    f"layer change to {target:.0f} m",
                )
            fly_for(link, 5.0)

        _phase(flight, link, "layer-change", layer, change, errors=False)


def _failsafe(
    flight: Flight, link: VehicleLink, companion: VehicleLink, mission: Mission, uav: int, world
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
            loiter.follow(_committed(companion, uav, mission))
            step_at[0] = companion.state.time_s

    settle(companion, link.frame, mission.altitude_of(uav), False, LEVEL_SETTLED_M, follow)
    error = arm_failsafe(loiter, _committed(companion, uav, mission))
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

    _phase(flight, link, "failsafe-loiter", mission.altitude_of(uav), silent)


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
    _phase(flight, link, "offboard", layer, lambda: fly_for(link, 2 * TURN_STEPS * k.step, turns))

    def hold() -> None:
        wait(
            link,
            lambda: link.state.custom_mode == PX4_HOLD,
            "Hold",
            _every(1.0, lambda: link.commands.set_mode(PX4_HOLD)),
        )
        fly_for(link, LOITER_S)

    _phase(flight, link, "hold", layer, hold)
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

    _phase(flight, link, "offboard-loss", layer, lost)
    flight.params = link.params.read(PX4_PARAMS)  # as the companion's take-over left them


# -- the autopilots' processes ----------------------------------------------------------------------
def on_free_ports(mission: Mission) -> Mission:
    """`mission` with every vehicle on a free block of loopback ports (the bundled simulator serves
    them all)."""
    bases = free_blocks(mission.n_uavs, width=6)
    ports = zip(mission.vehicles, bases, strict=True)
    vehicles = [msgspec.structs.replace(v, mavlink_port=p) for v, p in ports]
    return msgspec.structs.replace(mission, vehicles=tuple(vehicles))


@contextmanager
def running(
    autopilot: str, mission: Mission, uav: int, speedup: float, out: Path
) -> Iterator[tuple[str, str]]:
    """The autopilot of vehicle `uav` running: (observer URL, companion URL)."""
    children = Children()
    try:
        if autopilot == "ardupilot-sitl":
            binary = sitl.find_binary()
            home = out / "sitl"
            home.mkdir(parents=True, exist_ok=True)
            argv = sitl.sitl_argv(binary, sitl.find_defaults(binary), mission, uav, speedup)
            children.start("sitl", argv, out / "sitl.log", cwd=home, stop_signal=sitl.STOP_SIGNAL)
            ports = sitl.sitl_ports(mission, uav)
            yield ports.url(ports.serial0), ports.url(ports.serial1)
        elif autopilot == "px4-sitl":
            build = px4_sitl.find_build()
            px4 = px4_sitl.link_folder(build, out / "px4_bin")
            instance = px4_sitl.free_instances(1, 100)[0]
            workdir = out / "px4"
            shutil.rmtree(workdir, ignore_errors=True)
            workdir.mkdir(parents=True)
            env = px4_sitl.px4_env(mission, uav, speedup)
            children.start(
                "px4",
                px4_sitl.px4_argv(px4, build, instance, workdir),
                out / "px4.log",
                cwd=workdir,
                extra=env,
            )
            children.wait_for_line("px4", px4_sitl.STARTED)
            ports = px4_sitl.px4_ports(mission, uav)
            yield ports.url(ports.companion), ports.url(ports.gcs)
        else:
            path = out / "mission.toml"
            path.write_bytes(msgspec.toml.encode(_without_none(msgspec.to_builtins(mission))))
            argv = [
                sys.executable,
                "-m",
                "sim_vehicles",
                "--mission",
                str(path),
                "--speedup",
                f"{speedup:g}",
                "--no-camera",
            ]
            children.start("sim", argv, out / "sim.log")
            children.wait_for_line("sim", f"vehicle {uav} sysid")
            port = mission.vehicle_port(uav)
            yield f"udpout:127.0.0.1:{port}", f"udpout:127.0.0.1:{port}"
    finally:
        children.stop()


def _without_none(value: object) -> object:
    """A mission's builtins as TOML writes them: unset (None) fields left out."""
    if isinstance(value, dict):
        return {k: _without_none(v) for k, v in value.items() if v is not None}
    if isinstance(value, list | tuple):
        return [_without_none(v) for v in value]
    return value


def fly(
    autopilot: str,
    mission: Mission,
    uav: int,
    speedup: float,
    out: Path,
    phases: Sequence[str] = ARDUPILOT_PHASES,
    loiter_s: float = LOITER_S,
) -> Flight:
    """One autopilot's whole flight: start it, take off to the layer, fly the phases."""
    out.mkdir(parents=True, exist_ok=True)
    mission = on_free_ports(mission)
    if (mission.safety.failsafe_timeout or 0.0) < FAILSAFE_TIMEOUT_S:  # a starved companion must not fire it
        mission = msgspec.structs.replace(
            mission, safety=msgspec.structs.replace(mission.safety, failsafe_timeout=FAILSAFE_TIMEOUT_S)
        )
    frame = LocalFrame(mission.region.origin)
    flight = Flight(autopilot, out / "observer.tlog")
    flight.tlog.unlink(missing_ok=True)  # a tlog is appended to: an earlier flight's must not count
    layer = mission.altitude_of(uav)
    with running(autopilot, mission, uav, speedup, out) as (observer, companion):
        # it speaks (a ground station's HEARTBEAT) so that the bundled simulator keeps it as a peer
        link = VehicleLink(observer, frame, tlog=flight.tlog, component=GCS_COMPONENT, heartbeat=True)
        try:
            if not link.wait_heartbeat(120):
                raise BenchError(f"{autopilot}: no HEARTBEAT")
            flight.system = link.state.system
            link.request_streams()
            wait(link, lambda: link.state.has_pose, "a pose")
            stop = threading.Event()
            if autopilot == "px4-sitl":
                if not take_off_px4(link, layer, uav, stop):
                    raise BenchError("PX4 did not take off")
                fly_px4(flight, link, mission, uav)
            else:
                if autopilot == "bundled":
                    bundled_like_sitl(link)
                    guidance = Guidance(link, frame, mission, uav, "heading")
                    if not take_over(link, guidance, uav, stop):
                        raise BenchError("the bundled simulator was not taken over")
                elif not take_off(link, layer, uav, stop):
                    raise BenchError("ArduPlane did not take off")
                fly_ardupilot(flight, link, companion, mission, uav, phases, loiter_s)
        finally:
            link.close()
    return flight


def bundled_like_sitl(link: VehicleLink) -> None:
    """The bundled simulator set up as plane.parm sets ArduPlane SITL up (cruise, bank and loiter)."""
    for name, value in (("AIRSPEED_CRUISE", 22.0), ("ROLL_LIMIT_DEG", 65.0), ("WP_LOITER_RAD", 80.0)):
        if not link.params.set(name, value):
            raise BenchError(f"the bundled simulator: {name} = {value:g} not confirmed")


# -- report -------------------------------------------------------------------------------------------
def format_table(rows: Sequence[PhaseFigures]) -> str:
    head = (
        f"{'autopilot':<15} {'phase':<16} {'s':>5} {'max |err| m':>11} {'p95 m':>7} {'mean m':>7} "
        f"{'climb m/s':>9} {'sink m/s':>8}"
    )
    lines = [head, "-" * len(head)]
    for r in rows:
        lines.append(
            f"{r.autopilot:<15} {r.phase:<16} {r.seconds:>5.0f} {r.max_error_m:>11.2f} {r.p95_error_m:>7.2f} "
            f"{r.mean_error_m:>7.2f} {r.max_climb_ms:>9.2f} {r.max_sink_ms:>8.2f}"
        )
    return "\n".join(lines)


def proposal(rows: Sequence[PhaseFigures], margin: float) -> tuple[float, float]:
    """(the largest one-aircraft deviation over the guarantee's phases, the vertical separation it
    gives: twice that (two aircraft straying towards each other) plus `margin`)."""
    worst = max((r.max_error_m for r in rows if math.isfinite(r.max_error_m)), default=math.nan)
    return worst, 2.0 * worst + margin


def write_csv(path: Path, rows: Sequence[PhaseFigures]) -> None:
    with path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(list(PhaseFigures.__dataclass_fields__))
        for r in rows:
            w.writerow(
                [
                    getattr(r, k) if not isinstance(getattr(r, k), float) else f"{getattr(r, k):.3f}"
                    for k in PhaseFigures.__dataclass_fields__
                ]
            )


def bench_main(argv: Sequence[str] | None = None) -> int:
    """`uavsearch altitude-bench`: fly each autopilot, print the table, write the CSVs."""
    parser = argparse.ArgumentParser(
        prog="uavsearch altitude-bench",
        description="Altitude-keeping error of real autopilots (ArduPlane SITL, PX4 SITL) and of the bundled "
        "simulator in every phase the 3D separation relies on: max and p95 |altitude - layer|, climb "
        "and sink rates; proposes a vertical separation.",
    )
    parser.add_argument(
        "--autopilot",
        default="ardupilot-sitl,px4-sitl",
        help="comma-separated: ardupilot-sitl, px4-sitl, bundled (default: the two SITLs)",
    )
    parser.add_argument(
        "--mission", type=Path, help="mission file (default: scenario1_continuous, scenario1_px4)"
    )
    parser.add_argument(
        "--uav", type=natural, default=0, help="the vehicle that flies (its pose, layer; default 0)"
    )
    parser.add_argument("--speedup", type=positive, help="simulated time per wall second (default 8, PX4 2)")
    parser.add_argument(
        "--margin", type=weight, default=10.0, help="metres added to twice the worst deviation (default 10)"
    )
    parser.add_argument("--out", type=Path, help="output folder (default: a fresh temporary one)")
    args = parser.parse_args(argv)
    names = [a.strip() for a in args.autopilot.split(",") if a.strip()]
    unknown = [a for a in names if a not in MISSIONS]
    if unknown or not names:
        print(
            f"error: --autopilot: unknown {', '.join(unknown) or '(none)'} "
            "(one of ardupilot-sitl, px4-sitl, bundled)",
            file=sys.stderr,
        )
        return 2
    out = args.out or Path(tempfile.mkdtemp(prefix="altitude-bench-"))
    rows: list[PhaseFigures] = []
    every: list[tuple[str, Sample]] = []
    for name in names:
        mission = load_mission(args.mission or MISSIONS[name])
        if not 0 <= args.uav < mission.n_uavs:
            print(f"error: --uav {args.uav}: the mission has {mission.n_uavs} vehicles", file=sys.stderr)
            return 2
        print(
            f"{name}: flying vehicle {args.uav} at its layer {mission.altitude_of(args.uav):.0f} m",
            flush=True,
        )
        try:
            flight = fly(name, mission, args.uav, args.speedup or SPEEDUPS[name], out / name)
        except (BenchError, sitl.SitlError, px4_sitl.Px4Error, RuntimeError) as exc:
            print(f"error: {name}: {exc}", file=sys.stderr)
            return 1
        found, samples = flight_figures(flight)
        rows += found
        every += [(name, s) for s in samples]
        print("  " + ", ".join(f"{k} {v:g}" for k, v in sorted(flight.params.items())), flush=True)
    print(format_table(rows))
    guarantee = [r for r in rows if r.autopilot != "bundled"]
    worst, separation = proposal(guarantee or rows, args.margin)
    print(
        f"largest one-aircraft deviation {worst:.1f} m: vertical_separation >= 2 x {worst:.1f} + "
        f"{args.margin:g} m margin = {separation:.1f} m"
    )
    write_csv(out / "altitude.csv", rows)
    with (out / "samples.csv").open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["autopilot", "t_s", "up_m", "climb_ms"])
        w.writerows([n, f"{s.t:.2f}", f"{s.up:.2f}", f"{s.climb:.2f}"] for n, s in every)
    print(f"wrote {out / 'altitude.csv'} and {out / 'samples.csv'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(bench_main())
