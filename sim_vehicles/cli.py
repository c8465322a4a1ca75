"""Command line: `python -m sim_vehicles` / `uavsearch sim`.

`add_arguments(parser)` and `run(args)` let the project CLI mount the same command.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
from dataclasses import asdict
from pathlib import Path
from types import FrameType

from companion.contracts.arguments import HelpFormatter, check_mission, mission_argument, natural, positive
from companion.contracts.lifeline import end_with_launcher
from companion.contracts.mission import MissionError
from companion.core.feasibility import load_mission
from sim_vehicles.host import Host, HostOptions


def add_arguments(parser: argparse.ArgumentParser) -> None:
    mission_argument(parser, type=Path)
    parser.add_argument("--speedup", type=positive, default=1.0,
                        help="simulated seconds per wall second (default 1)")
    parser.add_argument("--lockstep", action="store_true",
                        help="advance simulated time only when every vehicle's driver allows it")
    parser.add_argument("--flavour", choices=("ardupilot", "px4"), default=None,
                        help="autopilot to imitate (default: the mission's sim.flavour)")
    parser.add_argument("--seed", type=natural, default=None, help="target seed (default: the mission's)")
    parser.add_argument("--host", default=None, help="address to bind (default: the mission's sim.host)")
    parser.add_argument("--no-camera", action="store_true", help="no camera, no Zenoh session")
    parser.add_argument("--zenoh-listen", action="append", default=None, metavar="ENDPOINT",
                        help="loopback Zenoh listen endpoint (default tcp/127.0.0.1:0)")
    parser.add_argument("--zenoh-connect", action="append", default=None, metavar="ENDPOINT",
                        help="loopback Zenoh endpoint to connect to (default: the mission's mesh)")
    parser.add_argument("--truth", type=Path, default=None,
                        help="write the ground-truth evaluation record (JSON) here (default: not written)")
    parser.add_argument("--approach", type=Path, default=None,
                        help="write every pair's closest approach per step, at the physics rate (CSV; "
                        "default: not written)")
    parser.add_argument("--state", type=Path, default=None,
                        help="save the simulator's state here every step, and resume from it if it exists "
                        "(default: not saved)")


def run(args: argparse.Namespace) -> int:
    """Run the simulator until SIGINT/SIGTERM; 0 on a clean stop, 2 on a bad mission or setup."""
    try:
        mission = load_mission(args.mission)
    except MissionError as exc:
        print(f"error: mission file {exc}", file=sys.stderr)
        return 2
    options = HostOptions(
        speedup=args.speedup, lockstep=args.lockstep, flavour=args.flavour, seed=args.seed,
        camera=not args.no_camera,
        zenoh_listen=tuple(args.zenoh_listen or ("tcp/127.0.0.1:0",)),
        zenoh_connect=tuple(args.zenoh_connect) if args.zenoh_connect else None,
        truth=args.truth, approach=args.approach, host=args.host, state=args.state,
    )
    try:
        host = Host(mission, options)
    except (OSError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2

    def on_signal(signum: int, frame: FrameType | None) -> None:
        host.stop()

    previous = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        flavour = options.flavour or mission.sim.flavour
        clock = "lockstep" if options.lockstep else f"speedup {options.speedup:g}"
        print(f"sim_vehicles: mission {mission.name}, {mission.n_uavs} vehicles, {flavour}, {clock}, "
              f"seed {host.seed}", flush=True)
        signing = "requires MAVLink2-signed input" if host.signed else "UNSIGNED: accepts any sender"
        if host.resumed:
            print(f"sim_vehicles: resumed from {options.state} at t = {host.t:.3f} s", flush=True)
        for index, ip, port in host.endpoints:
            print(f"vehicle {index} sysid {index + 1} mavlink udp {ip}:{port} ({signing})", flush=True)
        stats = host.run()
    finally:
        host.close()
        for s, handler in previous.items():
            signal.signal(s, handler)
    print(f"sim_vehicles stats: {json.dumps(asdict(stats))}", flush=True)
    return 0


def main(argv: list[str] | None = None) -> int:
    end_with_launcher()
    parser = argparse.ArgumentParser(
        prog="sim_vehicles", description=__doc__.splitlines()[0], formatter_class=HelpFormatter
    )
    add_arguments(parser)
    args = parser.parse_args(argv)
    check_mission(parser, args)
    return run(args)
