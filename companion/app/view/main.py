"""`uavsearch view`: serve the live map of a mission's mesh, or the replay of a run's output."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from companion.app.view.frames import links
from companion.app.view.server import Address, LiveSource, ReplaySource, Source, serve
from companion.contracts.arguments import mission_argument, natural, port
from companion.contracts.keys import for_mission, warn_if_insecure
from companion.core.feasibility import load_mission
from companion.core.uncertainty import apply_looks
from companion.core.world import build_world

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8765


def add_arguments(parser: argparse.ArgumentParser) -> None:
    mission_argument(
        parser, required=False, help="live: the mission whose mesh to follow (replay: its mission file)"
    )
    parser.add_argument(
        "--replay", help="a `uavsearch run` or `uavsearch mc --save-trajectories` output dir (default: live)"
    )
    parser.add_argument(
        "--seed", type=natural, default=None, help="live: the run's seed (default: the mission's)"
    )
    parser.add_argument(
        "--algorithm", default=None, help="replay: the algorithm of the run to show (default: the first)"
    )
    parser.add_argument(
        "--run", type=natural, default=None, help="replay: the run index to show (default: 0)"
    )
    parser.add_argument("--host", default=DEFAULT_HOST, help=f"address to serve on (default {DEFAULT_HOST})")
    parser.add_argument("--port", type=port, default=DEFAULT_PORT, help="port (0: any free port)")


def warm_kernels() -> None:
    """Load (or compile) the core kernels the listener calls, before the first frame needs them."""
    links(np.array([[0.0, 0.0], [1.0, 1.0], [2.0, 0.0]]), 10.0)
    apply_looks(np.ones(2), np.array([0, 1], dtype=np.int64), 0.5)


def run_view(args: argparse.Namespace) -> int:
    """Serve until SIGINT/SIGTERM: 0 then, 1 if the address cannot be bound, 2 for bad input."""
    source: Source
    if args.replay:
        mission_file = Path(args.mission) if args.mission else None
        source = ReplaySource(Path(args.replay), mission_file, args.algorithm, args.run)
    elif args.mission:
        mission = load_mission(args.mission)
        seed = mission.seed if args.seed is None else args.seed
        warn_if_insecure(mission)
        keys = for_mission(mission, "view")
        warm_kernels()
        source = LiveSource(build_world(mission, seed, 0), seed, keys)
    else:
        print("error: give --mission FILE (live) or --replay DIR", file=sys.stderr)
        return 2

    def ready(address: Address) -> None:
        print(f"view at {address.url}", flush=True)

    try:
        serve(source, args.host, args.port, ready)
    except OSError as exc:
        print(f"error: cannot serve on {args.host}:{args.port}: {exc.strerror or exc}", file=sys.stderr)
        return 1
    return 0
