"""Helpers for the simulator tests: free loopback ports, temporary missions, the simulator as a
real subprocess, and a small pymavlink client. Only 127.0.0.1 is ever used."""

from __future__ import annotations

import contextlib
import json
import math
import os
import signal
import subprocess
import sys
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil

from companion.app.loopback import free_ports

ROOT = Path(__file__).resolve().parents[2]
SCENARIO = ROOT / "mission_files" / "scenario1.toml"
STARTUP = 60.0  # generous: a loaded 2-core machine imports numpy, pymavlink and zenoh slowly
# A commanded point counts as reached when the vehicle is circling it: as ArduPlane (and PX4) do,
# the simulator flies onto the loiter circle (WP_LOITER_RAD, 76 m in these missions) and never
# over the point itself.
ARRIVED_M = 120.0
M = mavutil.mavlink


def free_tcp_port() -> int:
    return free_ports(1)[0]


def write_mission(
    directory: Path,
    *,
    n: int = 2,
    mode: str = "continuous",
    flavour: str = "ardupilot",
    sensor: str = "",
    sim: str = "",
    heading: float = 90.0,
    starts: list[tuple[float, float]] | None = None,
) -> tuple[Path, list[int], str]:
    """A mission derived from scenario1 with n vehicles on free ports and a unique key prefix."""
    text = SCENARIO.read_text(encoding="utf-8").split("[[vehicles]]")[0]
    text = text.replace('mode = "grid"', f'mode = "{mode}"')
    if sensor:
        text = text.replace("radius = 60.0", f"radius = 60.0\n{sensor}")
    *ports, seed = free_ports(n + 1)
    spacing = min(400.0, 1600.0 / max(1, n - 1))  # a connected line across the region
    starts = starts or [(-800.0 + spacing * i, -900.0) for i in range(n)]
    for (x, y), port in zip(starts, ports, strict=True):
        text += f"\n[[vehicles]]\nx = {x}\ny = {y}\nheading_deg = {heading}\nmavlink_port = {port}\n"
    prefix = f"simtest{uuid.uuid4().hex[:10]}"
    text += f'\n[sim]\nflavour = "{flavour}"\n{sim}\n'
    text += f'\n[mesh]\nkey_prefix = "{prefix}"\nseed_endpoint = "tcp/127.0.0.1:{seed}"\n'
    path = directory / f"mission-{prefix}.toml"
    path.write_text(text, encoding="utf-8")
    return path, ports, prefix


class SimProcess:
    """`python -m sim_vehicles` as a subprocess; stopped with SIGTERM, killed by PID if stuck."""

    def __init__(self, mission: Path, *args: str) -> None:
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "sim_vehicles", "--mission", str(mission), *args],
            cwd=ROOT,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        self.lines: list[str] = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.append(line.rstrip("\n"))

    def wait_ready(self, n: int) -> None:
        deadline = time.monotonic() + STARTUP
        while sum(line.startswith("vehicle ") for line in self.lines) < n:
            if self.proc.poll() is not None or time.monotonic() > deadline:
                raise AssertionError("simulator did not start:\n" + "\n".join(self.lines))
            time.sleep(0.05)

    def stop(self, signum: int = signal.SIGTERM) -> tuple[int, dict]:
        """Signal (SIGTERM by default), wait; (exit code, the final stats)."""
        if self.proc.poll() is None:
            self.proc.send_signal(signum)
        try:
            rc = self.proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            rc = self.proc.wait()
        self._reader.join(timeout=5)
        stats = next(
            (
                json.loads(line.split(": ", 1)[1])
                for line in self.lines
                if line.startswith("sim_vehicles stats: ")
            ),
            {},
        )
        return rc, stats

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()


@pytest.fixture
def start_sim() -> Iterator[Callable[..., SimProcess]]:
    started: list[SimProcess] = []

    def start(mission: Path, *args: str, n: int = 1) -> SimProcess:
        sim = SimProcess(mission, *args)
        started.append(sim)
        sim.wait_ready(n)
        return sim

    yield start
    for sim in started:
        sim.kill()


class Mav:
    """A pymavlink ground station on one vehicle's endpoint (udpout: the vehicle listens)."""

    def __init__(self, port: int, sysid: int = 1, source_system: int = 250) -> None:
        self.conn = mavutil.mavlink_connection(
            f"udpout:127.0.0.1:{port}", source_system=source_system, dialect="ardupilotmega"
        )
        self.sysid = sysid
        self.mav = self.conn.mav
        deadline = time.monotonic() + STARTUP
        while self.wait("HEARTBEAT", timeout=0.5, hello=True) is None:
            assert time.monotonic() < deadline, "no HEARTBEAT from the simulator"

    def hello(self) -> None:
        self.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)

    def wait(
        self,
        kind: str | list[str],
        cond: Callable[[object], bool] | None = None,
        timeout: float = 20.0,
        hello: bool = False,
    ) -> object | None:
        """The next message of `kind` from our vehicle satisfying `cond`, or None on timeout."""
        deadline = time.monotonic() + timeout
        if hello:
            self.hello()
        last_hello = time.monotonic()
        while (left := deadline - time.monotonic()) > 0:
            if time.monotonic() - last_hello > 1.0:
                self.hello()
                last_hello = time.monotonic()
            msg = self.conn.recv_match(type=kind, blocking=True, timeout=min(left, 0.5))
            if msg is None or msg.get_srcSystem() != self.sysid:
                continue
            if cond is None or cond(msg):
                return msg
        return None

    def need(
        self, kind: str | list[str], cond: Callable[[object], bool] | None = None, timeout: float = 20.0
    ) -> object:
        msg = self.wait(kind, cond, timeout)
        assert msg is not None, f"no {kind} within {timeout} s"
        return msg

    def command(self, command: int, *params: float, timeout: float = 10.0) -> int:
        p = [*params, *[0.0] * (7 - len(params))]
        self.mav.command_long_send(self.sysid, 1, command, 0, *p)
        ack = self.need("COMMAND_ACK", lambda m: m.command == command, timeout)
        return ack.result

    def command_int(
        self,
        command: int,
        frame: int,
        p1: float,
        p2: float,
        p3: float,
        p4: float,
        lat: float,
        lon: float,
        alt: float,
        timeout: float = 10.0,
    ) -> int:
        self.mav.command_int_send(
            self.sysid, 1, frame, command, 0, 0, p1, p2, p3, p4, round(lat * 1e7), round(lon * 1e7), alt
        )
        return self.need("COMMAND_ACK", lambda m: m.command == command, timeout).result

    def sim_time(self) -> float:
        return self.need("GLOBAL_POSITION_INT").time_boot_ms / 1000.0

    def position(self) -> tuple[float, float, float]:
        g = self.need("GLOBAL_POSITION_INT")
        return g.lat * 1e-7, g.lon * 1e-7, g.relative_alt / 1000.0

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self.conn.close()


def distance_m(lat1: float, lon1: float, lat2: float, lon2: float) -> float:
    """Local flat-earth distance (fine over a few km)."""
    dn = math.radians(lat2 - lat1) * 6_371_000.0
    de = math.radians(lon2 - lon1) * 6_371_000.0 * math.cos(math.radians(lat1))
    return math.hypot(dn, de)


def offset(lat: float, lon: float, north: float, east: float) -> tuple[float, float]:
    return (
        lat + math.degrees(north / 6_371_000.0),
        lon + math.degrees(east / (6_371_000.0 * math.cos(math.radians(lat)))),
    )


def fit_circle(points: list[tuple[float, float]]) -> tuple[float, float, float]:
    """Least-squares circle (centre x, centre y, radius) through local (x, y) points."""
    import numpy as np  # local: the rest of the helpers need no numpy

    p = np.asarray(points, dtype=float)
    a = np.c_[2 * p[:, 0], 2 * p[:, 1], np.ones(len(p))]
    cx, cy, c = np.linalg.lstsq(a, np.sum(p**2, axis=1), rcond=None)[0]
    return float(cx), float(cy), float(math.sqrt(c + cx * cx + cy * cy))
