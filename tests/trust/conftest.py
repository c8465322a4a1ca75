"""Fixtures of the authentication tests: a swarm's keys made at test time, and secured missions.

Keys are generated into the test's temporary directory (`uavsearch keys`'s own code); nothing
secret is ever committed. Processes and missions come from the end-to-end fixtures (real
processes, loopback only, stopped by PID).
"""

from __future__ import annotations

from pathlib import Path

import msgspec
import pytest

from companion.contracts import keys
from companion.contracts.mission import Mission
from companion.core.feasibility import load_mission
from tests.e2e.conftest import MissionFile, make_mission, procs, write_mission  # noqa: F401 (fixtures)
from tests.sim.conftest import start_sim  # noqa: F401 (fixture)
from tests.sitl.conftest import sitl_binary  # noqa: F401 (fixture)


@pytest.fixture
def key_dir(tmp_path: Path) -> Path:
    """Keys for scenario1's four UAVs (and the camera, view and router) in a fresh directory."""
    directory = tmp_path / "keys"
    keys.generate(directory, 4)
    return directory


def secured(mission: Mission, key_dir: Path, mavlink_signing: bool = True) -> Mission:
    """`mission` with `[security]` naming `key_dir`."""
    security = msgspec.structs.replace(mission.security, keys=str(key_dir), mavlink_signing=mavlink_signing)
    return msgspec.structs.replace(mission, security=security)


def secure_file(mission: MissionFile, key_dir: Path, mavlink_signing: bool = True) -> MissionFile:
    """The mission file with a `[security]` section naming `key_dir` (appended: TOML allows it)."""
    text = mission.path.read_text(encoding="utf-8")
    signing = "true" if mavlink_signing else "false"
    text += f'\n[security]\nkeys = "{key_dir}"\nmavlink_signing = {signing}\n'
    mission.path.write_text(text, encoding="utf-8")
    return MissionFile(mission.path, mission.ports, load_mission(mission.path))
