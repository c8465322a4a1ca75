"""The autopilot's return flies the UAV's layer: the companion's preflight (`return_altitude`) sets
ArduPlane's RTL_ALTITUDE, or PX4's RTL_RETURN_ALT and RTL_DESCEND_ALT, and the bundled simulator,
sent home, climbs to that altitude and circles home there."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from companion.contracts.frames import LocalFrame
from companion.core.feasibility import load_mission
from companion.node.return_altitude import set_return_altitude
from companion.node.vehicle_link import VehicleLink
from tests.sim.conftest import SimProcess, write_mission

LAYER = 145.0  # m above home: not the simulator's default return altitude (100 m) nor the start's
RTL_MODES = {"ardupilot": 11, "px4": (4 << 16) | (5 << 24)}  # RTL, AUTO.RTL
NAMES = {"ardupilot": ("RTL_ALTITUDE",), "px4": ("RTL_RETURN_ALT", "RTL_DESCEND_ALT")}
WITHIN_M = 1.0


@pytest.mark.parametrize("flavour", ["ardupilot", "px4"])
def test_return_flies_the_layer(flavour: str, tmp_path: Path) -> None:
    path, ports, _ = write_mission(tmp_path, n=1, flavour=flavour, starts=[(0.0, -600.0)])
    sim = SimProcess(path, "--speedup", "10", "--no-camera")
    link = None
    try:
        sim.wait_ready(1)
        link = VehicleLink(f"udpout:127.0.0.1:{ports[0]}", LocalFrame(load_mission(path).region.origin))
        assert link.wait_heartbeat(30)
        link.request_streams()
        assert set_return_altitude(link, LAYER) is None
        assert link.params.read(list(NAMES[flavour])) == dict.fromkeys(NAMES[flavour], LAYER)
        s = link.state
        deadline = time.monotonic() + 30
        while not (s.armed and s.custom_mode == RTL_MODES[flavour]):
            assert time.monotonic() < deadline, f"not armed in RTL: mode {s.custom_mode:#x}"
            link.commands.arm()
            link.commands.set_mode(RTL_MODES[flavour])
            link.poll(0.5)
        start = s.up
        end = s.time_s + 60.0  # 45 m at 5 m/s and the height loop's settling, with room
        while s.time_s < end and abs(s.up - LAYER) > WITHIN_M:
            link.poll(0.1)
        assert abs(s.up - LAYER) <= WITHIN_M, f"from {start:.1f} m: at {s.up:.1f} m, not {LAYER} m"
    finally:
        if link is not None:
            link.close()
        sim.kill()
