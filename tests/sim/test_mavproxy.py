"""MAVProxy (headless, commands piped to stdin) fetches parameters and the empty mission, sets
GUIDED and flies `guided LAT LON ALT`; a pymavlink monitor on the same vehicle checks arrival."""

from __future__ import annotations

import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from companion.core.feasibility import load_mission
from sim_vehicles.protocols.params import param_specs
from tests.sim.conftest import ARRIVED_M, Mav, distance_m, offset, write_mission


@pytest.mark.slow
def test_mavproxy_guided(tmp_path: Path, start_sim) -> None:
    path, ports, _ = write_mission(tmp_path, n=1)
    sim = start_sim(path, "--speedup", "5", "--no-camera", n=1)
    monitor = Mav(ports[0], 1)
    lat, lon, _ = monitor.position()
    tlat, tlon = offset(lat, lon, 500.0, -300.0)
    proxy = subprocess.Popen(
        [
            str(Path(sys.executable).parent / "mavproxy.py"),
            f"--master=udpout:127.0.0.1:{ports[0]}",
            "--state-basedir",
            str(tmp_path),
            "--logfile",
            str(tmp_path / "mav.tlog"),
        ],
        cwd=tmp_path,
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    out: list[str] = []
    try:
        assert proxy.stdin is not None and proxy.stdout is not None
        threading.Thread(target=lambda: out.extend(proxy.stdout), daemon=True).start()
        deadline = time.monotonic() + 60
        ardupilot_params = sum(p.ardupilot is not None for p in param_specs(load_mission(path)))
        received = f"Received {ardupilot_params} parameters"
        while not any(received in line for line in out):
            assert time.monotonic() < deadline, "".join(out)
            time.sleep(0.2)
        for command in ("wp list", "arm throttle", "mode GUIDED", f"guided {tlat:.7f} {tlon:.7f} 100"):
            proxy.stdin.write(command + "\n")
            proxy.stdin.flush()
            time.sleep(1.0)
        assert monitor.wait("HEARTBEAT", lambda m: m.custom_mode == 15, timeout=30), "".join(out)
        monitor.need(
            "GLOBAL_POSITION_INT",
            lambda g: distance_m(g.lat * 1e-7, g.lon * 1e-7, tlat, tlon) < ARRIVED_M,
            timeout=60,
        )
    finally:
        proxy.terminate()
        try:
            proxy.wait(timeout=15)
        except subprocess.TimeoutExpired:
            proxy.kill()
            proxy.wait()
    text = "".join(out)
    (tmp_path / "mavproxy.out").write_text(text)
    assert "Saved 1 waypoints" in text or "Requesting 1 waypoints" in text, text
    for bad in ("Traceback", "fence breach", "timeout"):
        assert bad not in text, text
    rc, _ = sim.stop()
    assert rc == 0
    monitor.close()
