"""PX4 SITL instances, one per UAV at its start pose (`uavsearch run --autopilot px4-sitl`).

The build is PX4's `px4_sitl_default` flying its own simulated fixed-wing (SIH,
`sihsim_airplane`), found from `--sitl-binary PATH`, $PX4_SITL_DIR or `../shared/px4`. Instance i
runs in its own working directory with a fresh folder of `px4-<module>` command links and our own
`px4-rc.mavlink`: home at vehicle i's start, PX4_SIM_SPEED_FACTOR = the speed-up, COM_OF_LOSS_T =
`OFFBOARD_LOSS_S` real seconds, the first free instance numbers from `first_instance`, and three
UDP MAVLink links from the mission's port P of vehicle i (companion P / P + 1, camera P + 2 / P + 3,
ground station P + 4 / P + 5), each client listening on its port. Why each of these:
docs/companion.md, "Flying PX4 SITL".
"""

from __future__ import annotations

import fcntl
import os
from dataclasses import dataclass
from pathlib import Path

from companion.contracts.frames import LocalFrame
from companion.contracts.mission import Mission

ENV = "PX4_SITL_DIR"
ROOT = Path(__file__).resolve().parents[2]
SHARED_DIR = ROOT.parent / "shared" / "px4"
AIRFRAME = "sihsim_airplane"
STARTED = "Startup script returned successfully"  # PX4's log line when it is up
PORT_ENV = "UAVSEARCH_MAVLINK_PORT"
LOSS_ENV = "UAVSEARCH_OF_LOSS_T"
MAX_INSTANCE = 254  # MAV_SYS_ID = instance + 1
OFFBOARD_LOSS_S = 3.0  # real seconds the setpoint stream may pause (PX4's default COM_OF_LOSS_T: 1 s)
OFFBOARD_LOSS_MAX_S = 60.0  # COM_OF_LOSS_T's maximum
# Replaces PX4's SITL MAVLink set-up (etc/init.d-posix/px4-rc.mavlink): three links of fixed ports,
# and COM_OF_LOSS_T (rcS sets it from PX4_SIM_SPEED_FACTOR after the PX4_PARAM_* overrides).
RC_MAVLINK = f"""#!/bin/sh
# uavsearch: the companion's, the camera's and a ground station's MAVLink links (see px4_sitl.py)
[ -n "${LOSS_ENV}" ] && param set COM_OF_LOSS_T ${LOSS_ENV}
p=${PORT_ENV}
mavlink start -x -u $((p + 1)) -o $p -r 4000000 -m onboard
mavlink start -x -u $((p + 3)) -o $((p + 2)) -r 1000000
mavlink start -x -u $((p + 5)) -o $((p + 4)) -r 1000000
"""


class Px4Error(RuntimeError):
    """The PX4 build cannot be used (the message says which part and why)."""


@dataclass(frozen=True)
class Px4Build:
    binary: Path  # bin/px4
    romfs: Path  # etc/
    commands: tuple[str, ...]  # the px4-<module> names its start-up scripts call


def find_build(explicit: str | Path | None = None) -> Px4Build:
    """The PX4 SITL build: the binary `explicit`, else $PX4_SITL_DIR/bin/px4, else ../shared/px4."""
    if explicit:
        binary = Path(explicit).expanduser()
        where = f"--sitl-binary {binary}"
    else:
        folder = Path(os.environ.get(ENV) or SHARED_DIR).expanduser()
        binary = folder / "bin" / "px4"
        where = f"{ENV}={folder}" if os.environ.get(ENV) else f"{folder} (set {ENV})"
    if not binary.is_file() or not os.access(binary, os.X_OK):
        raise Px4Error(f"PX4 SITL binary {binary} not found or not executable: {where}")
    binary = binary.resolve()
    romfs = binary.parent.parent / "etc"
    if not (romfs / "init.d-posix" / "rcS").is_file():
        raise Px4Error(f"PX4 SITL build {binary.parent.parent}: no ROMFS (etc/init.d-posix/rcS) next to bin/")
    commands = tuple(
        sorted(
            p.name
            for p in binary.parent.iterdir()
            if p.name.startswith("px4-") and p.name != "px4-alias.sh" and "." not in p.name
        )
    )
    listed = binary.parent.parent / "commands.txt"
    if not commands and listed.is_file():
        commands = tuple(line.strip() for line in listed.read_text().splitlines() if line.strip())
    if not commands or not (binary.parent / "px4-alias.sh").is_file():
        raise Px4Error(f"PX4 SITL build {binary.parent}: no px4-<module> commands or px4-alias.sh by px4")
    return Px4Build(binary, romfs, commands)


def link_folder(build: Px4Build, folder: Path) -> Path:
    """`folder` made into the binary's folder of command links and our MAVLink set-up; the px4 to run."""
    folder.mkdir(parents=True, exist_ok=True)
    targets = {"px4": build.binary, "px4-alias.sh": build.binary.parent / "px4-alias.sh"}
    targets |= {name: build.binary for name in build.commands}
    for name, target in targets.items():
        link = folder / name
        if link.is_symlink() or link.exists():
            link.unlink()
        link.symlink_to(target)
    rc = folder / "px4-rc.mavlink"
    rc.write_text(RC_MAVLINK)
    rc.chmod(0o755)
    return folder / "px4"


@dataclass(frozen=True)
class Px4Ports:
    """One instance's MAVLink links: each client listens on its port, PX4 on the next one."""

    companion: int
    camera: int
    gcs: int

    @staticmethod
    def url(port: int) -> str:
        return f"udpin:127.0.0.1:{port}"

    def all(self) -> list[int]:
        return [p + d for p in (self.companion, self.camera, self.gcs) for d in (0, 1)]


def px4_ports(mission: Mission, i: int) -> Px4Ports:
    base = mission.vehicle_port(i)
    return Px4Ports(base, base + 2, base + 4)


def instance_free(instance: int) -> bool:
    """Whether no PX4 runs as `instance` (PX4 holds a lock on /tmp/px4_lock-I while it runs)."""
    try:
        fd = os.open(f"/tmp/px4_lock-{instance}", os.O_RDWR)
    except FileNotFoundError:
        return True
    except OSError:
        return False
    try:
        fcntl.lockf(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        return False
    else:
        fcntl.lockf(fd, fcntl.LOCK_UN)
        return True
    finally:
        os.close(fd)


def free_instances(n: int, first: int = 0) -> list[int]:
    """n PX4 instance numbers from `first` on that no running PX4 holds."""
    found = [i for i in range(first, MAX_INSTANCE + 1) if instance_free(i)][:n]
    if len(found) < n:
        raise Px4Error(f"no {n} free PX4 instances from {first} (each holds /tmp/px4_lock-I)")
    return found


def home(mission: Mission, i: int) -> tuple[float, float, float]:
    """Vehicle i's start: (lat, lon, the mission origin's altitude)."""
    v = mission.vehicles[i]
    return LocalFrame(mission.region.origin).to_geodetic(v.x, v.y)


def px4_env(mission: Mission, i: int, speedup: float) -> dict[str, str]:
    """The environment of vehicle i's instance (on top of the caller's)."""
    lat, lon, alt = home(mission, i)
    return {
        "HEADLESS": "1",
        "PX4_SIM_MODEL": AIRFRAME,
        "PX4_SIMULATOR": "sihsim",
        "PX4_HOME_LAT": f"{lat:.8f}",
        "PX4_HOME_LON": f"{lon:.8f}",
        "PX4_HOME_ALT": f"{alt:.2f}",
        "PX4_SIM_SPEED_FACTOR": f"{speedup:g}",
        LOSS_ENV: f"{min(OFFBOARD_LOSS_S * max(speedup, 1.0), OFFBOARD_LOSS_MAX_S):g}",
        PORT_ENV: str(px4_ports(mission, i).companion),
    }


def px4_argv(px4: Path, build: Px4Build, instance: int, workdir: Path) -> list[str]:
    """The command line of one instance (`px4` from `link_folder`; run it in `workdir`)."""
    return [str(px4), "-d", "-i", str(instance), "-w", str(workdir), str(build.romfs)]
