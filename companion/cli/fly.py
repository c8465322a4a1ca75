"""`uavsearch run`, `companion`, `keys`, `view`, `router`, `sim` and `camera`: flying a swarm."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from companion.cli.options import Subparsers
from companion.contracts.arguments import count, mission_argument, natural, port, positive, step_count
from companion.core.feasibility import load_mission


def _companion(args: argparse.Namespace) -> int:
    """`uavsearch companion`: one UAV's companion process."""
    from companion.node.main import run_companion

    return run_companion(args)


def _run(args: argparse.Namespace) -> int:
    """`uavsearch run`: the whole swarm with one command."""
    from companion.app.launcher import run_mission
    from companion.app.run_options import RunOptions

    options = RunOptions(
        mission_file=Path(args.mission),
        out=Path(args.out),
        speedup=args.speedup,
        lockstep=args.lockstep,
        steps=args.steps,
        seed=args.seed,
        command_mode=args.command_mode,
        flavour=args.flavour,
        progress=not args.quiet,
        keep_going=args.keep_going,
        view=args.view,
        view_port=args.view_port,
        autopilot=args.autopilot,
        vehicles=_links(args.vehicles),
        camera_links=_links(args.camera_links),
        sitl_binary=args.sitl_binary,
        sitl_defaults=args.sitl_defaults,
        sitl_instance=args.sitl_instance,
    )
    try:
        return run_mission(options)
    except RuntimeError as exc:  # a child that did not start (its log is in the message)
        print(f"error: {exc}", file=sys.stderr)
        return 1


def _keys(args: argparse.Namespace) -> int:
    """`uavsearch keys`: a swarm's keys and certificates, or one UAV's signing key rotated."""
    from companion.contracts.keys import KeyDirectoryError, generate, rotate

    mission = load_mission(args.mission) if args.mission else None
    n_uavs = mission.n_uavs if mission else args.uavs
    out = args.out or (mission.security.keys if mission else None)
    if args.rotate is not None and out:
        try:
            rotate(Path(out), args.rotate)
        except KeyDirectoryError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        print(
            f"uav-{args.rotate} has a new sign.key in {out}, listed first in swarm.json beside its previous "
            f"one: copy swarm.json to every aircraft, then restart uav {args.rotate}'s companion alone"
        )
        return 0
    if not n_uavs or n_uavs < 1 or not out:
        print(
            "error: give --mission FILE (with [security] keys or --out DIR), or --uavs N --out DIR",
            file=sys.stderr,
        )
        return 2
    if args.days < 1:
        print("error: --days must be at least 1", file=sys.stderr)
        return 2
    generate(Path(out), n_uavs, args.days)
    print(
        f"wrote keys for {n_uavs} UAVs in {out}: each aircraft needs swarm.json, ca.pem and its "
        "uav-N/ folder; keep ca.key off the aircraft"
    )
    return 0


def _view(args: argparse.Namespace) -> int:
    """`uavsearch view`: the live map, or a run's replay."""
    from companion.app.view.main import run_view

    return run_view(args)


def _links(text: str | None) -> tuple[str, ...]:
    """Comma-separated links as a tuple (none for none)."""
    return tuple(u.strip() for u in (text or "").split(",") if u.strip())


def _router(args: argparse.Namespace) -> int:
    """`uavsearch router`: a Zenoh router for client-mode meshes."""
    from companion.node.mesh import router_main

    argv = ["--endpoint", args.endpoint] if args.endpoint else []
    return router_main([*argv, *(["--mission", args.mission] if args.mission else [])])


def _sim(args: argparse.Namespace) -> int:
    """`uavsearch sim`: the MAVLink fixed-wing simulator."""
    from sim_vehicles.cli import run

    return run(args)


def _camera(args: argparse.Namespace) -> int:
    """`uavsearch camera`: the stand-alone simulated camera."""
    from companion.app.camera_node import run

    return run(args)


def _add_companion(sub: Subparsers) -> None:
    """Add `companion`: one UAV's companion process."""
    from companion.node.guidance import COMMAND_MODES

    co = sub.add_parser("companion", help="the companion process of one UAV (MAVLink + Zenoh mesh)")
    mission_argument(co)
    co.add_argument(
        "--uav", type=natural, required=True, help="UAV index (0-based; MAVLink system id - 1; required)"
    )
    co.add_argument(
        "--vehicle",
        default=None,
        help="pymavlink connection string (udp/udpin/udpout/tcp/serial); default: the simulator",
    )
    co.add_argument(
        "--command-mode",
        choices=COMMAND_MODES,
        default="turn-rate",
        help="how the plan is sent (docs/companion.md)",
    )
    co.add_argument(
        "--takeover",
        action="store_true",
        help="take off if on the ground, switch the vehicle to its guided mode and arm it",
    )
    co.add_argument(
        "--fence",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="upload the region plus its margin as the autopilot's fence (default: with --takeover)",
    )
    co.add_argument(
        "--failsafe",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="make the autopilot circle the loiter of the trajectory in force when the companion falls "
        "silent (ArduPilot's GCS failsafe; default: with --takeover)",
    )
    co.add_argument(
        "--gcs-reports",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="show the search to ground stations through the autopilot's links: targets, progress, "
        "health, the peers as ADS-B traffic (docs/companion.md; default: on)",
    )
    co.add_argument("--lockstep", action="store_true", help="step together with the simulator and the swarm")
    co.add_argument("--steps", type=step_count, default=None, help="steps to fly (default: the mission's)")
    co.add_argument("--seed", type=natural, default=None, help="target seed (default: the mission's)")
    co.add_argument(
        "--out",
        default=None,
        help="directory for the step log, the report and the .tlog (default: none written)",
    )
    co.add_argument(
        "--journal",
        default=None,
        help="journal file: every step is kept there, and a companion started again on it goes on "
        "where it stopped (docs/reliability.md; default: none)",
    )
    co.add_argument(
        "--mavlink-key",
        default=None,
        help="sign the MAVLink link with this secret file (64 hex digits; default: the vehicle's in the "
        "mission's key directory when [security] mavlink_signing is on)",
    )
    co.add_argument(
        "--run",
        default=None,
        help="the run identity the swarm agreed on (default: $UAVSEARCH_RUN, else the journal's): bound "
        "into every signature (docs/reliability.md)",
    )
    co.set_defaults(func=_companion)


def _add_keys(sub: Subparsers) -> None:
    """Add `keys`: a swarm's keys and certificates."""
    ke = sub.add_parser("keys", help="generate a swarm's keys and certificates (docs/reliability.md)")
    mission_argument(
        ke, required=False, help="the mission: its UAV count, and its key directory (or --uavs and --out)"
    )
    ke.add_argument(
        "--uavs", type=count, default=None, help="the UAV count (without a mission; default: none)"
    )
    ke.add_argument("--out", default=None, help="the key directory (default: the mission's security.keys)")
    ke.add_argument("--days", type=count, default=365, help="how long the certificates are valid")
    ke.add_argument(
        "--rotate",
        type=natural,
        default=None,
        metavar="UAV",
        help="give this UAV a new signing key in an existing key directory, its previous one still "
        "accepted (default: none: write a new directory)",
    )
    ke.set_defaults(func=_keys)


def _add_run(sub: Subparsers) -> None:
    """Add `run`: the whole swarm with one command."""
    from companion.node.guidance import COMMAND_MODES

    ru = sub.add_parser("run", help="simulator + one companion per UAV: a full simulated mission")
    mission_argument(ru)
    ru.add_argument(
        "--speedup", type=positive, default=10.0, help="times real time the vehicles fly (SITL: their clocks)"
    )
    ru.add_argument(
        "--lockstep", action="store_true", help="the bundled simulator waits for every companion at each step"
    )
    ru.add_argument(
        "--steps", type=step_count, default=None, help="the most steps to fly (default: the mission's steps)"
    )
    ru.add_argument("--seed", type=natural, default=None, help="target seed (default: the mission's seed)")
    ru.add_argument("--out", default="out/run", help="output folder (reports, plots, logs, .tlogs)")
    ru.add_argument(
        "--command-mode",
        choices=COMMAND_MODES,
        default=None,
        help="how the plan is sent (docs/companion.md; default: turn-rate on the bundled simulator, "
        "position-target on PX4 SITL, heading otherwise)",
    )
    ru.add_argument(
        "--flavour",
        choices=("ardupilot", "px4"),
        default=None,
        help="the bundled simulator's autopilot flavour (only with --autopilot bundled: a SITL autopilot is "
        "its own flavour; default: the mission's sim.flavour)",
    )
    ru.add_argument(
        "--autopilot",
        choices=("bundled", "ardupilot-sitl", "px4-sitl"),
        default="bundled",
        help="the bundled simulator (its flavour: --flavour), or one ArduPlane or PX4 SITL per UAV at its "
        "start pose",
    )
    ru.add_argument(
        "--vehicles",
        default=None,
        help="fly vehicles that exist: one pymavlink URL per UAV, comma-separated (default: start them)",
    )
    ru.add_argument(
        "--camera-links",
        default=None,
        help="with --vehicles: links for the stand-alone simulated camera (default: no camera)",
    )
    ru.add_argument(
        "--sitl-binary",
        default=None,
        help="ArduPlane SITL binary (default: $ARDUPLANE_SITL, else ../shared/sitl/arduplane), PX4 bin/px4 "
        "(default: $PX4_SITL_DIR/bin/px4, else ../shared/px4/bin/px4)",
    )
    ru.add_argument(
        "--sitl-instance",
        type=natural,
        default=0,
        help="PX4: the first instance number tried (MAV_SYS_ID - 1)",
    )
    ru.add_argument(
        "--sitl-defaults",
        default=None,
        help="ArduPlane SITL parameter defaults file (default: plane.parm in the binary's folder)",
    )
    ru.add_argument("--quiet", action="store_true", help="no progress lines")
    ru.add_argument(
        "--keep-going",
        action="store_true",
        help="fly all the steps even when every target is found (default: stop once every target is found)",
    )
    ru.add_argument("--view", action="store_true", help="serve the live map of the swarm (uavsearch view)")
    ru.add_argument("--view-port", type=port, default=0, help="the live map's port (0: any free port)")
    ru.set_defaults(func=_run)


def _add_processes(sub: Subparsers) -> None:
    """Add `view`, `router`, `sim` and `camera`: a flight's other processes."""
    from companion.app.view.main import add_arguments as add_view_arguments

    vi = sub.add_parser("view", help="live map of a mission's swarm, or replay of a run, in the browser")
    add_view_arguments(vi)
    vi.set_defaults(func=_view)

    ro = sub.add_parser("router", help="a Zenoh router for client-mode meshes")
    mission_argument(ro, required=False, help="the mission whose mesh.router endpoint to listen on")
    ro.add_argument(
        "--endpoint",
        default=None,
        help="the endpoint to listen on, instead of a mission's (default: tcp/127.0.0.1:7447)",
    )
    ro.set_defaults(func=_router)

    from sim_vehicles.cli import add_arguments

    si = sub.add_parser("sim", help="the MAVLink fixed-wing simulator (all the mission's vehicles)")
    add_arguments(si)
    si.set_defaults(func=_sim)
    from companion.app import camera_node

    ca = sub.add_parser(
        "camera", help="a stand-alone simulated camera for external vehicles (e.g. ArduPlane SITL)"
    )
    camera_node.add_arguments(ca)
    ca.set_defaults(func=_camera)


def register(sub: Subparsers) -> None:
    """Add `companion`, `keys`, `run`, `view`, `router`, `sim` and `camera` to the subcommands."""
    _add_companion(sub)
    _add_keys(sub)
    _add_run(sub)
    _add_processes(sub)
