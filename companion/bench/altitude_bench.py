"""Altitude keeping of real autopilots: how far each strays from its layer in the 3D separation's phases.

`uavsearch altitude-bench [--autopilot ardupilot-sitl,px4-sitl,bundled] [--out DIR]` (or
`bench_main(argv)`) flies one vehicle of the mission (`--uav I`, at `Mission.altitude_of(I)`) on
each autopilot in turn through the phases of `altitude_phases`, and prints per phase the largest
and 95th percentile of |altitude - layer| and the fastest climb and sink, from the vehicle's
GLOBAL_POSITION_INT in the observer's .tlog (`altitude_figures`); `altitude.csv` in `--out` holds
the table, `samples.csv` every sample. Processes are started and stopped by PID on free loopback
ports. See docs/companion.md ("Altitude keeping"; issue 32).
"""

from __future__ import annotations

import argparse
import csv
import shutil
import sys
import tempfile
import threading
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

import msgspec

from companion.app import px4_sitl, sitl
from companion.app.children import Children
from companion.app.loopback import free_blocks
from companion.bench.altitude_figures import (
    BenchError,
    Flight,
    PhaseFigures,
    Sample,
    flight_figures,
    format_table,
    proposal,
    write_csv,
)
from companion.bench.altitude_phases import ARDUPILOT_PHASES, LOITER_S, fly_ardupilot, fly_px4, wait
from companion.contracts.arguments import natural, positive, weight
from companion.contracts.frames import LocalFrame
from companion.contracts.mission import Mission
from companion.core.feasibility import load_mission
from companion.node.guidance import Guidance
from companion.node.takeover import take_off, take_off_px4, take_over
from companion.node.vehicle_link import VehicleLink

ROOT = Path(__file__).resolve().parents[2]
MISSIONS = {
    "ardupilot-sitl": ROOT / "mission_files" / "scenario1_continuous.toml",
    "px4-sitl": ROOT / "mission_files" / "scenario1_px4.toml",
    "bundled": ROOT / "mission_files" / "scenario1_continuous.toml",
}
SPEEDUPS = {"ardupilot-sitl": 8.0, "px4-sitl": 2.0, "bundled": 8.0}  # PX4 at 4: OFFBOARD lost when busy
GCS_COMPONENT = 190  # MAV_COMP_ID_MISSIONPLANNER: the bench's observer
FAILSAFE_TIMEOUT_S = 10.0  # FS_LONG_TIMEOUT flown (vehicle s): 1.25 s of wall time at 8x, as tests/sitl


def on_free_ports(mission: Mission) -> Mission:
    """`mission` with every vehicle on a free block of loopback ports.

    `mission` with every vehicle on a free block of loopback ports (the bundled simulator serves
    them all)."""
    bases = free_blocks(mission.n_uavs, width=6)
    ports = zip(mission.vehicles, bases, strict=True)
    vehicles = [msgspec.structs.replace(v, mavlink_port=p) for v, p in ports]
    return msgspec.structs.replace(mission, vehicles=tuple(vehicles))


@contextmanager
def running(
    autopilot: str, mission: Mission, uav: int, speedup: float, out: Path
) -> Iterator[tuple[str, str]]:
    """The autopilot of vehicle `uav` running: (observer URL, companion URL)."""
    children = Children()
    try:
        if autopilot == "ardupilot-sitl":
            binary = sitl.find_binary()
            home = out / "sitl"
            home.mkdir(parents=True, exist_ok=True)
            argv = sitl.sitl_argv(binary, sitl.find_defaults(binary), mission, uav, speedup)
            children.start("sitl", argv, out / "sitl.log", cwd=home, stop_signal=sitl.STOP_SIGNAL)
            ports = sitl.sitl_ports(mission, uav)
            yield ports.url(ports.serial0), ports.url(ports.serial1)
        elif autopilot == "px4-sitl":
            build = px4_sitl.find_build()
            px4 = px4_sitl.link_folder(build, out / "px4_bin")
            instance = px4_sitl.free_instances(1, 100)[0]
            workdir = out / "px4"
            shutil.rmtree(workdir, ignore_errors=True)
            workdir.mkdir(parents=True)
            env = px4_sitl.px4_env(mission, uav, speedup)
            children.start(
                "px4",
                px4_sitl.px4_argv(px4, build, instance, workdir),
                out / "px4.log",
                cwd=workdir,
                extra=env,
            )
            children.wait_for_line("px4", px4_sitl.STARTED)
            px4_ports = px4_sitl.px4_ports(mission, uav)
            yield px4_ports.url(px4_ports.companion), px4_ports.url(px4_ports.gcs)
        else:
            path = out / "mission.toml"
            path.write_bytes(msgspec.toml.encode(_without_none(msgspec.to_builtins(mission))))
            argv = [
                sys.executable,
                "-m",
                "sim_vehicles",
                "--mission",
                str(path),
                "--speedup",
                f"{speedup:g}",
                "--no-camera",
            ]
            children.start("sim", argv, out / "sim.log")
            children.wait_for_line("sim", f"vehicle {uav} sysid")
            port = mission.vehicle_port(uav)
            yield f"udpout:127.0.0.1:{port}", f"udpout:127.0.0.1:{port}"
    finally:
        children.stop()


def _without_none(value: object) -> object:
    """A mission's builtins as TOML writes them: unset (None) fields left out."""
    if isinstance(value, dict):
        return {k: _without_none(v) for k, v in value.items() if v is not None}
    if isinstance(value, list | tuple):
        return [_without_none(v) for v in value]
    return value


def fly(
    autopilot: str,
    mission: Mission,
    uav: int,
    speedup: float,
    out: Path,
    phases: Sequence[str] = ARDUPILOT_PHASES,
    loiter_s: float = LOITER_S,
) -> Flight:
    """One autopilot's whole flight: start it, take off to the layer, fly the phases."""
    out.mkdir(parents=True, exist_ok=True)
    mission = on_free_ports(mission)
    if (mission.safety.failsafe_timeout or 0.0) < FAILSAFE_TIMEOUT_S:  # a starved companion must not fire it
        mission = msgspec.structs.replace(
            mission, safety=msgspec.structs.replace(mission.safety, failsafe_timeout=FAILSAFE_TIMEOUT_S)
        )
    frame = LocalFrame(mission.region.origin)
    flight = Flight(autopilot, out / "observer.tlog")
    flight.tlog.unlink(missing_ok=True)  # a tlog is appended to: an earlier flight's must not count
    layer = mission.altitude_of(uav)
    with running(autopilot, mission, uav, speedup, out) as (observer, companion):
        # it speaks (a ground station's HEARTBEAT) so that the bundled simulator keeps it as a peer
        link = VehicleLink(observer, frame, tlog=flight.tlog, component=GCS_COMPONENT, heartbeat=True)
        try:
            if not link.wait_heartbeat(120):
                raise BenchError(f"{autopilot}: no HEARTBEAT")
            flight.system = link.state.system
            link.request_streams()
            wait(link, lambda: link.state.has_pose, "a pose")
            stop = threading.Event()
            if autopilot == "px4-sitl":
                if not take_off_px4(link, layer, uav, stop):
                    raise BenchError("PX4 did not take off")
                fly_px4(flight, link, mission, uav)
            else:
                if autopilot == "bundled":
                    bundled_like_sitl(link)
                    guidance = Guidance(link, frame, mission, uav, "heading")
                    if not take_over(link, guidance, uav, stop):
                        raise BenchError("the bundled simulator was not taken over")
                elif not take_off(link, layer, uav, stop):
                    raise BenchError("ArduPlane did not take off")
                fly_ardupilot(flight, link, companion, mission, uav, phases, loiter_s)
        finally:
            link.close()
    return flight


def bundled_like_sitl(link: VehicleLink) -> None:
    """The bundled simulator set up as plane.parm sets ArduPlane SITL up (cruise, bank and loiter)."""
    for name, value in (("AIRSPEED_CRUISE", 22.0), ("ROLL_LIMIT_DEG", 65.0), ("WP_LOITER_RAD", 80.0)):
        if not link.params.set(name, value):
            raise BenchError(f"the bundled simulator: {name} = {value:g} not confirmed")



def bench_main(argv: Sequence[str] | None = None) -> int:
    """`uavsearch altitude-bench`: fly each autopilot, print the table, write the CSVs."""
    parser = argparse.ArgumentParser(
        prog="uavsearch altitude-bench",
        description="Altitude-keeping error of real autopilots (ArduPlane SITL, PX4 SITL) and of the bundled "
        "simulator in every phase the 3D separation relies on: max and p95 |altitude - layer|, climb "
        "and sink rates; proposes a vertical separation.",
    )
    parser.add_argument(
        "--autopilot",
        default="ardupilot-sitl,px4-sitl",
        help="comma-separated: ardupilot-sitl, px4-sitl, bundled (default: the two SITLs)",
    )
    parser.add_argument(
        "--mission", type=Path, help="mission file (default: scenario1_continuous, scenario1_px4)"
    )
    parser.add_argument(
        "--uav", type=natural, default=0, help="the vehicle that flies (its pose, layer; default 0)"
    )
    parser.add_argument("--speedup", type=positive, help="simulated time per wall second (default 8, PX4 2)")
    parser.add_argument(
        "--margin", type=weight, default=10.0, help="metres added to twice the worst deviation (default 10)"
    )
    parser.add_argument("--out", type=Path, help="output folder (default: a fresh temporary one)")
    args = parser.parse_args(argv)
    names = [a.strip() for a in args.autopilot.split(",") if a.strip()]
    unknown = [a for a in names if a not in MISSIONS]
    if unknown or not names:
        print(
            f"error: --autopilot: unknown {', '.join(unknown) or '(none)'} "
            "(one of ardupilot-sitl, px4-sitl, bundled)",
            file=sys.stderr,
        )
        return 2
    out = args.out or Path(tempfile.mkdtemp(prefix="altitude-bench-"))
    rows: list[PhaseFigures] = []
    every: list[tuple[str, Sample]] = []
    for name in names:
        mission = load_mission(args.mission or MISSIONS[name])
        if not 0 <= args.uav < mission.n_uavs:
            print(f"error: --uav {args.uav}: the mission has {mission.n_uavs} vehicles", file=sys.stderr)
            return 2
        print(
            f"{name}: flying vehicle {args.uav} at its layer {mission.altitude_of(args.uav):.0f} m",
            flush=True,
        )
        try:
            flight = fly(name, mission, args.uav, args.speedup or SPEEDUPS[name], out / name)
        except (BenchError, sitl.SitlError, px4_sitl.Px4Error, RuntimeError) as exc:
            print(f"error: {name}: {exc}", file=sys.stderr)
            return 1
        found, samples = flight_figures(flight)
        rows += found
        every += [(name, s) for s in samples]
        print("  " + ", ".join(f"{k} {v:g}" for k, v in sorted(flight.params.items())), flush=True)
    print(format_table(rows))
    guarantee = [r for r in rows if r.autopilot != "bundled"]
    worst, separation = proposal(guarantee or rows, args.margin)
    print(
        f"largest one-aircraft deviation {worst:.1f} m: vertical_separation >= 2 x {worst:.1f} + "
        f"{args.margin:g} m margin = {separation:.1f} m"
    )
    write_csv(out / "altitude.csv", rows)
    with (out / "samples.csv").open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["autopilot", "t_s", "up_m", "climb_ms"])
        w.writerows([n, f"{s.t:.2f}", f"{s.up:.2f}", f"{s.climb:.2f}"] for n, s in every)
    print(f"wrote {out / 'altitude.csv'} and {out / 'samples.csv'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(bench_main())
