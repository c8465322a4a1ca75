"""ArduPlane SITL for the tests: the real autopilot, found from ARDUPLANE_SITL or ../shared/sitl.

Without the binary the tests are skipped, except under CI=true, where a missing binary fails them.
Missions are scenario1_continuous on free loopback ports (each SITL instance uses its vehicle's port
P for SERIAL0, P + 2 and P + 3 for SERIAL1 and SERIAL2, P + 5 for RC input) and a key space of
their own. Processes are started and stopped by PID (tests.e2e.conftest.Proc).
"""

from __future__ import annotations

import contextlib
import os
import threading
import time
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.app import sitl
from companion.app.loopback import free_blocks
from companion.contracts.frames import LocalFrame
from companion.contracts.mission import Mission
from companion.core.feasibility import load_mission
from companion.node.takeover import take_off
from companion.node.vehicle_link import ARDUPILOT_GUIDED, LinkError, VehicleLink, open_link
from tests.e2e.conftest import ROOT, Proc

CONTINUOUS = ROOT / "mission_files" / "scenario1_continuous.toml"
# The companions' failsafe timeout (FS_LONG_TIMEOUT): 10 s, 2.5 s of wall time at 4x, 1.25 s at 8x
# (ArduPlane's 5 s would be 0.6 s at 8x, less than a companion may be starved on a busy machine).
SLACK_FAILSAFE_TIMEOUT = "failsafe_timeout = 10.0"
GCS_COMPONENT = 190  # MAV_COMP_ID_MISSIONPLANNER: the tests' ground station
STARTUP_S = 180.0  # generous: SITL boots slowly on a busy 2-core machine


@pytest.fixture(scope="session")
def sitl_binary() -> Path:
    try:
        return sitl.find_binary()
    except sitl.SitlError as exc:
        if os.environ.get("CI") == "true":
            pytest.fail(f"CI=true needs ArduPlane SITL: {exc}")
        pytest.skip(str(exc))


def free_bases(n: int) -> list[int]:
    """n port blocks P..P+5 free for TCP and UDP on 127.0.0.1, below the ephemeral range."""
    return free_blocks(n, width=6)


@dataclass(frozen=True)
class SitlMission:
    path: Path
    mission: Mission

    def ports(self, i: int) -> sitl.SitlPorts:
        return sitl.sitl_ports(self.mission, i)


def write_autopilot_mission(
    directory: Path, text: str, name: str, tag: str, n: int, starts: list[tuple[float, float]] | None
) -> Path:
    """Mission `text` (named `name`) under a fresh name and key space: its first n vehicles (or
    vehicles at `starts`, heading north) on free ports, the mesh on free ports, no pass criteria."""
    head, *vehicles = text.split("[[vehicles]]")
    vehicles[-1] = vehicles[-1].split("[pass_criteria]")[0]
    bodies = [f"\nx = {x}\ny = {y}\nheading_deg = 90.0\n" for x, y in starts] if starts else vehicles[:n]
    prefix = f"{tag}{uuid.uuid4().hex[:12]}"
    bases = free_bases(len(bodies) + 1)
    out = head.replace(f'name = "{name}"', f'name = "{prefix}"')
    for body, port in zip(bodies, bases, strict=False):
        out += "[[vehicles]]" + body.rstrip() + f"\nmavlink_port = {port}\n\n"
    mesh = bases[-1]
    out += f'[mesh]\nkey_prefix = "{prefix}"\nseed_endpoint = "tcp/127.0.0.1:{mesh}"\n'
    out += f'router = "tcp/127.0.0.1:{mesh + 1}"\n\n[pass_criteria]\nmin_targets_found = 0\n'
    path = directory / f"{prefix}.toml"
    path.write_text(out, encoding="utf-8")
    return path


def write_mission(
    directory: Path,
    n: int,
    starts: list[tuple[float, float]] | None = None,
    grid: bool = False,
    safety: str = SLACK_FAILSAFE_TIMEOUT,
    extra: str = "",
    base: Path = CONTINUOUS,
) -> SitlMission:
    """`base` (scenario1_continuous) with its first n vehicles (or vehicles at `starts`, heading
    north), the `[safety]` section's lines `safety`, and the TOML text `extra` at the end.

    Continuous kinematics unless `grid`; a `[region] area` file is found where `base` is."""
    text = base.read_text(encoding="utf-8").replace('area = "', f'area = "{base.parent}/')
    text = text.replace('mode = "grid"', 'mode = "continuous"')
    if grid:
        text = text.replace('mode = "continuous"', 'mode = "grid"')
    path = write_autopilot_mission(directory, text, base.stem, "sitl", n, starts)
    with path.open("a", encoding="utf-8") as f:
        f.write(f"\n[safety]\n{safety}\n{extra}")
    return SitlMission(path, load_mission(path))


def start_sitl(binary: Path, mission: SitlMission, i: int, speedup: float, directory: Path) -> Proc:
    home = directory / f"sitl{i}"
    home.mkdir(parents=True, exist_ok=True)
    defaults = sitl.find_defaults(binary)
    argv = sitl.sitl_argv(binary, defaults, mission.mission, i, speedup)
    return Proc(f"sitl{i}", argv, home / "out.log", cwd=home, stop_signal=sitl.STOP_SIGNAL)


class Airborne:
    """One SITL instance flying in GUIDED, with the tests' ground station on its SERIAL0.

    SITL stalls when a client's TCP buffer fills up, so a thread keeps reading the ground station's
    link whenever a test is not using it (`use()`).
    """

    def __init__(self, binary: Path, mission: SitlMission, speedup: float, directory: Path) -> None:
        self.mission = mission
        self.frame = LocalFrame(mission.mission.region.origin)
        self.proc = start_sitl(binary, mission, 0, speedup, directory)
        url = mission.ports(0).url(mission.ports(0).serial0)
        gone = lambda: not self.proc.alive()  # noqa: E731
        link = open_link(url, self.frame, STARTUP_S, gone, component=GCS_COMPONENT)
        assert link is not None, self.proc.text()
        self.link = link
        try:
            assert self.link.wait_heartbeat(STARTUP_S, gone), f"SITL exited:\n{self.proc.text()}"
        except LinkError as exc:
            raise AssertionError(f"{exc}; SITL's output:\n{self.proc.text()}") from exc
        self.link.request_streams()
        while not self.link.state.has_pose:
            self.link.poll(0.2)
        stop = threading.Event()
        assert take_off(self.link, mission.mission.altitude_of(0), 0, stop), "SITL did not take off"
        self.guided()
        self._lock, self._stop = threading.Lock(), threading.Event()
        self._reader = threading.Thread(target=self._drain, daemon=True)
        self._reader.start()

    def _drain(self) -> None:
        while not self._stop.is_set():
            with self._lock:
                self.link.poll(0.05)
            time.sleep(0.005)

    @contextlib.contextmanager
    def use(self) -> Iterator[VehicleLink]:
        """The ground station's link, for the test alone while the block runs."""
        with self._lock:
            yield self.link

    def guided(self) -> None:
        s = self.link.state
        deadline = time.monotonic() + 30
        while s.custom_mode != ARDUPILOT_GUIDED:
            assert time.monotonic() < deadline, "SITL did not take GUIDED"
            self.link.commands.set_mode(ARDUPILOT_GUIDED)
            self.link.poll(1.0)

    def fly_to(self, x: float, y: float, within: float = 250.0, timeout: float = 120.0) -> None:
        """Fence and GCS failsafe off (a companion may have enabled them), GUIDED, DO_REPOSITION
        to (x, y) at the mission altitude; returns once within `within` m (call it inside `use()`)."""
        assert self.link.command_ack(mavlink.MAV_CMD_DO_FENCE_ENABLE, 0) == mavlink.MAV_RESULT_ACCEPTED
        assert self.link.params.set("FS_GCS_ENABL", 0.0)
        self.guided()
        lat, lon, _ = self.frame.to_geodetic(x, y)
        s = self.link.state
        deadline = time.monotonic() + timeout
        while (s.x - x) ** 2 + (s.y - y) ** 2 > within**2:
            assert time.monotonic() < deadline, f"SITL did not reach ({x}, {y}): at ({s.x:.0f}, {s.y:.0f})"
            self.link.commands.reposition(lat, lon, self.mission.mission.altitude_of(0))
            self.link.poll(1.0)

    def close(self) -> None:
        self._stop.set()
        self._reader.join(timeout=5)
        self.link.close()
        self.proc.stop()


@pytest.fixture(scope="module")
def airborne(sitl_binary: Path, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Airborne]:
    """A module's SITL instance, airborne in GUIDED near the region's centre (speedup 8)."""
    directory = tmp_path_factory.mktemp("sitl")
    plane = Airborne(sitl_binary, write_mission(directory, 1, starts=[(0.0, -600.0)]), 8.0, directory)
    try:
        yield plane
    finally:
        plane.close()
