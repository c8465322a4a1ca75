"""PX4 SITL for the tests: the real autopilot (SIH fixed-wing), found from PX4_SITL_DIR or ../shared/px4.

Without the build the tests are skipped, except under CI=true, where a missing build fails them.
Missions are scenario1_px4 on free loopback port blocks (each instance's links use its vehicle's
port P to P + 5, companion.app.px4_sitl) and a key space of their own, with the origin 30 m above
sea level: PX4's altitude reference then reaches the ground 15 s after boot
(`takeover.px4_ready_at`), so the take-off hardly waits, while altitudes above home and AMSL still
differ. PX4 instances are numbered from a random
free one above 100 (PX4 holds /tmp/px4_lock-I while it runs), so that tests running at the same
time, and a developer's instances 0, 1, ..., do not collide. PX4 runs at SPEEDUP times real time
(PX4_SIM_SPEED_FACTOR; SIH steps PX4's clock in lockstep with its controllers, so a busy machine
slows PX4's time down rather than its flight), a swarm at SWARM_SPEEDUP. Processes are started
and stopped by PID (tests.e2e.conftest.Proc).
"""

from __future__ import annotations

import os
import random
import threading
import time
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from companion.app import px4_sitl
from companion.contracts.frames import LocalFrame
from companion.contracts.mission import Mission
from companion.core.feasibility import load_mission
from companion.node.takeover import take_off_px4
from companion.node.vehicle_link import PX4_HOLD, VehicleLink
from tests.e2e.conftest import ROOT, Proc
from tests.sitl.conftest import GCS_COMPONENT, write_autopilot_mission

SCENARIO = ROOT / "mission_files" / "scenario1_px4.toml"
SPEEDUP = 4.0  # a step is half a second of wall time: at 8 a busy machine made turns come late
SWARM_SPEEDUP = 2.0  # three instances, three companions and the camera on two cores (at 4 a loaded
# machine starved the setpoint streams)
FIRST_INSTANCE = 100
ORIGIN_ALT = 30.0


@pytest.fixture(scope="session")
def px4_build() -> px4_sitl.Px4Build:
    try:
        return px4_sitl.find_build()
    except px4_sitl.Px4Error as exc:
        if os.environ.get("CI") == "true":
            pytest.fail(f"CI=true needs PX4 SITL: {exc}")
        pytest.skip(str(exc))


def first_instance() -> int:
    """Where to start looking for free PX4 instance numbers (random, above FIRST_INSTANCE)."""
    return FIRST_INSTANCE + random.Random(uuid.uuid4().int).randrange(100)


@dataclass(frozen=True)
class Px4Mission:
    path: Path
    mission: Mission

    def ports(self, i: int) -> px4_sitl.Px4Ports:
        return px4_sitl.px4_ports(self.mission, i)


def write_mission(directory: Path, n: int, starts: list[tuple[float, float]] | None = None) -> Px4Mission:
    """scenario1_px4 at ORIGIN_ALT with its first n vehicles (or vehicles at `starts`, heading north)."""
    text = SCENARIO.read_text(encoding="utf-8").replace("alt = 488.0", f"alt = {ORIGIN_ALT}")
    path = write_autopilot_mission(directory, text, "scenario1_px4", "px4", n, starts)
    return Px4Mission(path, load_mission(path))


def start_px4(build: px4_sitl.Px4Build, mission: Px4Mission, i: int, directory: Path) -> Proc:
    """Vehicle i's PX4 instance, up (its start-up script done)."""
    workdir = directory / f"px4_{i}"
    workdir.mkdir(parents=True, exist_ok=True)
    px4 = px4_sitl.link_folder(build, directory / "px4_bin")
    instance = px4_sitl.free_instances(1, first_instance())[0]
    env = px4_sitl.px4_env(mission.mission, i, SPEEDUP)
    argv = px4_sitl.px4_argv(px4, build, instance, workdir)
    proc = Proc(f"px4_{i}", argv, directory / f"px4_{i}.log", cwd=workdir, env=env)
    proc.wait_for_text(px4_sitl.STARTED, timeout=120)
    return proc


class Px4Airborne:
    """One PX4 instance airborne in Hold, with the tests' ground station on its ground-station link."""

    def __init__(self, build: px4_sitl.Px4Build, mission: Px4Mission, directory: Path) -> None:
        self.mission = mission
        self.frame = LocalFrame(mission.mission.region.origin)
        self.proc = start_px4(build, mission, 0, directory)
        ports = mission.ports(0)
        self.link = VehicleLink(ports.url(ports.gcs), self.frame, component=GCS_COMPONENT)
        self.link.wait_heartbeat(60)
        self.link.request_streams()
        while not self.link.state.has_pose:
            self.link.poll(0.2)
        altitude = mission.mission.altitude_of(0)
        assert take_off_px4(self.link, altitude, 0, threading.Event()), "PX4 did not take off"

    def fly_to(self, x: float, y: float, within: float = 250.0, timeout: float = 120.0) -> None:
        """Hold, DO_REPOSITION to (x, y) at the mission altitude (inside the region: a companion's
        fence may be in force); returns once within `within` m (wall `timeout`)."""
        lat, lon, _ = self.frame.to_geodetic(x, y)
        s = self.link.state
        deadline = time.monotonic() + timeout
        while (s.x - x) ** 2 + (s.y - y) ** 2 > within**2 or s.custom_mode != PX4_HOLD:
            assert time.monotonic() < deadline, f"PX4 did not reach ({x}, {y}): at ({s.x:.0f}, {s.y:.0f})"
            self.link.commands.reposition(lat, lon, self.mission.mission.altitude_of(0))
            self.link.poll(1.0)

    def close(self) -> None:
        self.link.close()
        self.proc.stop()


@pytest.fixture(scope="module")
def px4_airborne(
    px4_build: px4_sitl.Px4Build, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[Px4Airborne]:
    """A module's PX4 instance, airborne in Hold south of the region's centre."""
    directory = tmp_path_factory.mktemp("px4")
    plane = Px4Airborne(px4_build, write_mission(directory, 1, starts=[(0.0, -900.0)]), directory)
    try:
        yield plane
    finally:
        plane.close()
