"""A vehicle endpoint whose UDP port is taken (another simulator of the same mission, most often)
is `error: ... vehicle I's MAVLink endpoint udp HOST:PORT: Address already in use` and exit 2: the
error names what could not be bound (it said only "[Errno 98] Address already in use")."""

from __future__ import annotations

import socket
import subprocess
import sys
from pathlib import Path

from tests.sim.conftest import ROOT, STARTUP, write_mission


def test_a_taken_vehicle_port_is_named(tmp_path: Path) -> None:
    path, ports, _ = write_mission(tmp_path, n=2)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as taken:
        taken.bind(("127.0.0.1", ports[1]))
        done = subprocess.run(
            [sys.executable, "-m", "sim_vehicles", "--mission", str(path)],
            cwd=ROOT, capture_output=True, text=True, timeout=STARTUP,
        )  # fmt: skip
    assert done.returncode == 2, done.stdout + done.stderr
    expected = f"vehicle 1's MAVLink endpoint udp 127.0.0.1:{ports[1]}: Address already in use"
    assert done.stderr.startswith("error: ") and expected in done.stderr, done.stderr
    assert "Traceback" not in done.stderr
