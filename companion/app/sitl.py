"""ArduPlane SITL instances, one per UAV at its start pose (`uavsearch run --autopilot ardupilot-sitl`).

The binary is ArduPilot's software-in-the-loop ArduPlane; it is not part of the project. It is
found from `--sitl-binary`, the environment variable ARDUPLANE_SITL or `../shared/sitl/arduplane`
relative to the repository root; its parameter defaults (`plane.parm`) from `--sitl-defaults` or
next to the binary.

Instance i runs in its own working directory (it writes eeprom.bin, logs/, terrain/), with system
id i + 1, home at vehicle i's start pose (the mission's origin altitude, its heading) and its TCP
ports from the mission's port of vehicle i, P = `mission.vehicle_port(i)`: SERIAL0 on P (simulated
time starts when a client connects there), SERIAL1 on P + 2, SERIAL2 on P + 3, RC input UDP P + 5.
SITL exits when its parent process exits. `uavsearch run` adds RUN_PARAMS to the defaults (ADS-B on).
"""

from __future__ import annotations

import math
import os
import signal
from dataclasses import dataclass
from pathlib import Path

from companion.contracts.frames import LocalFrame, heading_to_yaw
from companion.contracts.mission import Mission

ENV = "ARDUPLANE_SITL"
STOP_SIGNAL = signal.SIGTERM  # what SITL exits cleanly on (AP_HAL_SITL's exit_signal_handler)
ROOT = Path(__file__).resolve().parents[2]
SHARED_BINARY = ROOT.parent / "shared" / "sitl" / "arduplane"
# What `uavsearch run` sets on top of the defaults: ADS-B on (uAvionix over MAVLink), as on an
# aircraft with an ADS-B receiver, so ArduPlane lists the peers its companion reports and sends
# them to every ground station as its own traffic (docs/companion.md, "Traffic"). Its avoidance
# (AVD_ENABLE, off by default) stays off: separation is the companions' (algorithm.md).
RUN_PARAMS = {"ADSB_TYPE": 1}


class SitlError(RuntimeError):
    """The SITL binary or its defaults cannot be used (the message says which and why)."""


def find_binary(explicit: str | Path | None = None) -> Path:
    """The SITL binary: `explicit`, else $ARDUPLANE_SITL, else ../shared/sitl/arduplane."""
    chosen = explicit or os.environ.get(ENV) or SHARED_BINARY
    path = Path(chosen).expanduser()
    if not path.is_file() or not os.access(path, os.X_OK):
        raise SitlError(
            f"ArduPlane SITL binary {path} not found or not executable: give --sitl-binary PATH or set {ENV}"
        )
    return path.resolve()


def find_defaults(binary: Path, explicit: str | Path | None = None) -> Path:
    """The parameter defaults SITL's plane model needs: `explicit`, else plane.parm next to the binary."""
    path = Path(explicit).expanduser() if explicit else binary.parent / "plane.parm"
    if not path.is_file():
        raise SitlError(f"SITL parameter defaults {path} not found: give --sitl-defaults PATH")
    return path.resolve()


@dataclass(frozen=True)
class SitlPorts:
    """One instance's TCP serial ports (MAVLink) and its RC input UDP port, all on 127.0.0.1."""

    serial0: int
    serial1: int
    serial2: int
    rc_in: int

    def url(self, port: int) -> str:
        return f"tcp:127.0.0.1:{port}"


def sitl_ports(mission: Mission, i: int) -> SitlPorts:
    base = mission.vehicle_port(i)
    return SitlPorts(base, base + 2, base + 3, base + 5)


def home(mission: Mission, i: int) -> str:
    """SITL's --home of vehicle i: its start position, the origin's altitude, its heading (deg from north)."""
    v = mission.vehicles[i]
    lat, lon, alt = LocalFrame(mission.region.origin).to_geodetic(v.x, v.y)
    yaw = math.degrees(heading_to_yaw(math.radians(v.heading_deg))) % 360.0
    return f"{lat:.8f},{lon:.8f},{alt:.2f},{yaw:.1f}"


def write_run_params(directory: Path) -> Path:
    """RUN_PARAMS as a parameter file in `directory` (an instance's), for `sitl_argv`'s `extra`."""
    path = directory / "run.parm"
    path.write_text("".join(f"{name} {value}\n" for name, value in RUN_PARAMS.items()), encoding="utf-8")
    return path


def sitl_argv(
    binary: Path, defaults: Path, mission: Mission, i: int, speedup: float, extra: Path | None = None
) -> list[str]:
    """The command line of vehicle i's instance (run it in a directory of its own).

    `extra`: a parameter file loaded after `defaults`, its values taking precedence."""
    ports = sitl_ports(mission, i)
    return [
        str(binary),
        "--wipe",
        "--model",
        "plane",
        "--speedup",
        f"{speedup:g}",
        "--defaults",
        ",".join(str(p) for p in (defaults, extra) if p is not None),
        "--home",
        home(mission, i),
        "--base-port",
        str(ports.serial0),
        "--rc-in-port",
        str(ports.rc_in),
        "--sysid",
        str(i + 1),
        "--instance",
        "0",
    ]
