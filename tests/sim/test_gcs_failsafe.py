"""ArduPlane's GCS failsafe on the bundled simulator, armed by the companion's own code.

A companion-like link (the companion's system id, HEARTBEATs from `poll`) arms the failsafe with
`companion.node.failsafe.arm_failsafe` on a vehicle flying a heading in GUIDED. While it polls,
nothing happens; when it falls silent the vehicle flies on for FS_LONG_TIMEOUT, says "GCS Failsafe
On: AUTO" and circles the loiter it was armed with (the committed loiter of a trajectory ahead of
it) at its altitude layer, as wide as ArduPlane flies it; a ground station's HEARTBEATs (another
system) do not stop that. When the link speaks again the
failsafe clears and the mode stays AUTO. With FS_LONG_ACTN 0 the vehicle stays in GUIDED.
A simulator that was not scheduled for a while (a busy machine) slips its clock rather than running
ahead in a burst, so a companion that kept speaking does not trip the failsafe; and a companion
that was not scheduled for a while costs real time, not speedup times it (`RealTimeClock.pace`).
"""

from __future__ import annotations

import math
import signal
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from companion.contracts.frames import LocalFrame
from companion.contracts.mission import Mission
from companion.core.feasibility import load_mission
from companion.core.trajectory import Trajectory
from companion.core.world import FAILSAFE_WIDE, build_world
from companion.node.failsafe import FailsafeLoiter, arm_failsafe
from companion.node.vehicle_link import COMPANION_SYSTEM, HEARTBEAT_VEHICLE_S, VehicleLink
from tests.sim.conftest import M, Mav, SimProcess, fit_circle, write_mission

GUIDED, AUTO = 15, 10


@pytest.fixture
def flying(tmp_path: Path) -> Iterator[tuple[VehicleLink, Mav, Path, SimProcess]]:
    path, ports, _ = write_mission(tmp_path, n=1, starts=[(0.0, -600.0)])
    sim = SimProcess(path, "--speedup", "10", "--no-camera")
    link = None
    try:
        sim.wait_ready(1)
        ground = Mav(ports[0])
        mission = load_mission(path)
        link = VehicleLink(
            f"udpout:127.0.0.1:{ports[0]}",
            LocalFrame(mission.region.origin),
            system=COMPANION_SYSTEM,
            heartbeat=True,
        )
        link.wait_heartbeat(30)
        link.request_streams()
        assert ground.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_ACCEPTED
        assert ground.command(M.MAV_CMD_DO_SET_MODE, 1, GUIDED) == M.MAV_RESULT_ACCEPTED
        yield link, ground, path, sim
    finally:
        if link is not None:
            link.close()
        sim.kill()


def _poll_for(link: VehicleLink, seconds: float) -> None:
    """Poll (and so send HEARTBEATs) for `seconds` of vehicle time."""
    s = link.state
    link.poll(0.1)  # what came while it was silent, first
    while not s.has_pose:
        link.poll(0.1)
    end = s.time_s + seconds
    while s.time_s < end:
        link.poll(0.05)


def _text(ground: Mav, text: str, timeout: float = 30.0) -> float:
    """Wait for STATUSTEXT `text`; the vehicle time of the next position (s)."""
    ground.need("STATUSTEXT", lambda m: m.text == text, timeout)
    return ground.sim_time()


def test_silent_companion_makes_the_vehicle_circle_its_committed_loiter(flying) -> None:
    link, ground, path, _ = flying
    mission = load_mission(path)
    world = build_world(mission)
    link.commands.change_heading(90.0, 5.0)  # east, straight on
    while not link.state.has_pose:
        link.poll(0.1)
    s = link.state  # committed: straight on for the plan's steps, then a clockwise loiter
    committed = Trajectory(0, s.x, s.y, s.heading, (0.0,) * mission.algorithm.horizon, -1)
    loiter = FailsafeLoiter(link, world, 0, link.frame)
    assert arm_failsafe(loiter, committed) is None
    centre = loiter.current[:2]
    _poll_for(link, 12.0)  # heard: no failsafe
    assert link.state.custom_mode == GUIDED and not any("Failsafe" in t for t in link.state.texts)

    # the last HEARTBEAT went out at most HEARTBEAT_VEHICLE_S of vehicle time before the latest state
    silent_from = link.state.time_s - HEARTBEAT_VEHICLE_S
    ground.need("STATUSTEXT", lambda m: m.text == "Mission: 1 LoitUnlim", timeout=30)  # as ArduPlane
    t_on = _text(ground, "GCS Failsafe On: AUTO")
    frame = LocalFrame(mission.region.origin)
    assert t_on >= silent_from + mission.failsafe_seconds
    assert ground.need("HEARTBEAT").custom_mode == AUTO

    track, ups = [], []
    while ground.sim_time() < t_on + 90:  # ground's HEARTBEATs (system 250) go on: not the GCS
        g = ground.need("GLOBAL_POSITION_INT")
        track.append(frame.to_local(g.lat * 1e-7, g.lon * 1e-7))
        ups.append(g.relative_alt * 1e-3)
    radius = world.safety.loiter_radius
    circling = track[len(track) // 2 :]
    assert max(math.dist(p, centre) for p in circling) < world.safety.failsafe_reach
    cx, cy, r = fit_circle(circling)
    assert math.dist((cx, cy), centre) < 10.0, (cx, cy, centre)
    assert radius < r < FAILSAFE_WIDE * radius, (r, radius)
    assert abs(ups[-1] - mission.altitude_of(0)) < 5.0
    assert ground.need("HEARTBEAT").custom_mode == AUTO

    link.poll(0.05)  # the companion speaks again: cleared...
    ground.need("STATUSTEXT", lambda m: m.text == "GCS Failsafe Cleared")
    _poll_for(link, 3.0)
    assert ground.need("HEARTBEAT").custom_mode == AUTO  # ...and the mode stays

    assert ground.command(M.MAV_CMD_DO_SET_MODE, 1, GUIDED) == M.MAV_RESULT_ACCEPTED
    assert link.params.set("FS_LONG_ACTN", 0.0)  # continue: the failsafe changes nothing in GUIDED
    _poll_for(link, 1.0)
    _text(ground, "GCS Failsafe On: GUIDED")
    assert ground.need("HEARTBEAT").custom_mode == GUIDED


def _armed_on_a_heading(link: VehicleLink, path: Path) -> Mission:
    """Fly east on a heading, the failsafe armed on a loiter straight ahead, 3 s heard."""
    mission = load_mission(path)
    link.commands.change_heading(90.0, 5.0)
    while not link.state.has_pose:
        link.poll(0.1)
    s = link.state
    committed = Trajectory(0, s.x, s.y, s.heading, (0.0,) * mission.algorithm.horizon, -1)
    assert arm_failsafe(FailsafeLoiter(link, build_world(mission), 0, link.frame), committed) is None
    _poll_for(link, 3.0)
    return mission


def test_a_stalled_simulator_slips_instead_of_tripping_the_failsafe(flying) -> None:
    link, ground, path, sim = flying
    mission = _armed_on_a_heading(link, path)
    stall = 2 * mission.failsafe_seconds / 10  # wall seconds: twice the timeout at 10x
    sim.proc.send_signal(signal.SIGSTOP)
    try:
        end = time.monotonic() + stall
        while time.monotonic() < end:  # the companion goes on speaking to a stopped simulator
            link.poll(0.05)
    finally:
        sim.proc.send_signal(signal.SIGCONT)
    _poll_for(link, 2 * mission.failsafe_seconds)
    assert not any("Failsafe" in t for t in link.state.texts), link.state.texts
    assert ground.need("HEARTBEAT").custom_mode == GUIDED
    _, stats = sim.stop()
    assert stats["slipped"] >= 0.5 * stall * 10, stats  # simulated time given up, not run in a burst


def test_a_stalled_companion_costs_real_time_not_speedup_times_it(flying) -> None:
    """A companion not scheduled for 0.3 s of wall time at --speedup 10 would miss 3 s of simulated
    time, more than FS_LONG_TIMEOUT (2 s); once its silence passes `host.GCS_QUIET_S` the clock
    runs at real time, so it misses about 1.2 s and the failsafe does not fire."""
    link, ground, path, sim = flying
    mission = _armed_on_a_heading(link, path)
    stall = 1.5 * mission.failsafe_seconds / 10  # wall seconds: 1.5 timeouts at 10x
    before = link.state.time_s
    time.sleep(stall)  # not a HEARTBEAT sent meanwhile
    _poll_for(link, 2 * mission.failsafe_seconds)
    assert not any("Failsafe" in t for t in link.state.texts), link.state.texts
    assert ground.need("HEARTBEAT").custom_mode == GUIDED
    _, stats = sim.stop()
    assert stats["paced"] > 0, stats
    assert link.state.time_s > before
