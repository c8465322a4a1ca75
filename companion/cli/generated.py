"""`uavsearch generate` and `soak`: generated missions, and the safety soak flown on them."""

from __future__ import annotations

import argparse
from pathlib import Path

from companion.cli.options import ALGORITHM_LIST, Subparsers, add_executor_arguments, family, family_options
from companion.contracts.arguments import count, fraction, names, natural
from companion.contracts.mission import ALGORITHMS


def _generate(args: argparse.Namespace) -> int:
    """`uavsearch generate`: generated missions written as mission files."""
    from companion.batch.generate import generate, write

    paths = write(generate(args.count, args.seed, family(args)), Path(args.out))
    print(f"wrote {len(paths)} missions to {args.out}/")
    return 0


def _soak(args: argparse.Namespace) -> int:
    """`uavsearch soak`: every algorithm on generated missions; exit 1 on any event."""
    from rich.console import Console

    from companion.batch.executors import open_executor
    from companion.batch.soak import soak, soak_specs

    algorithms = tuple(args.algorithms)
    specs = soak_specs(args.missions, args.seed, args.steps, algorithms, args.loss, args.kill, family(args))
    console = Console(highlight=False)
    runs = events = 0
    with open_executor(args.scheduler, args.workers) as executor:
        for row in soak(specs, executor=executor):
            runs += 1
            events += not row.clean
            if args.verbose or row.separation_losses or row.link_losses or row.keepout_entries:
                killed = f" killed {row.killed[0][0]}@{row.killed[0][1]}" if row.killed else ""
                console.print(
                    f"{row.mission} {row.mode} {row.uavs} UAVs {row.algorithm}{killed}: "
                    f"{row.separation_losses} separation, {row.link_losses} link events, "
                    f"{row.keepout_entries} keep-out entries, "
                    f"closest approach {row.closest_approach:.1f} m, "
                    f"found {row.targets_found}/{row.targets}",
                    style=None if row.clean else "bold red",
                )
    what = "a separation event" if args.kill else "a separation or link event"
    what += " or a keep-out entry" if args.zones[1] else ""
    print(f"{runs} runs of {args.missions} generated missions: {events} with {what}")
    return 1 if events else 0


def register(sub: Subparsers) -> None:
    """Add `generate` and `soak` to the subcommands."""
    ge = sub.add_parser("generate", help="write generated missions (a family beyond the scenario files)")
    ge.add_argument("--count", type=count, required=True, help="how many missions (required)")
    ge.add_argument("--seed", type=natural, required=True, help="the generator's seed (required)")
    ge.add_argument("--out", required=True, help="output folder (required)")
    family_options(ge)
    ge.set_defaults(func=_generate)

    so = sub.add_parser("soak", help="safety soak: separation and link events on generated missions")
    so.add_argument("--missions", type=count, default=20, help="generated missions")
    so.add_argument("--seed", type=natural, default=1, help="the generator's seed")
    so.add_argument(
        "--algorithms",
        type=names(ALGORITHMS),
        default="proposed,no-ta,pheromone",
        help=f"algorithms, {ALGORITHM_LIST}",
    )
    so.add_argument("--loss", type=fraction, default=0.0, help="message loss probability on the radio")
    so.add_argument("--kill", action="store_true", help="one companion per mission dies mid-run")
    add_executor_arguments(so)
    so.add_argument("--verbose", action="store_true", help="print every run, not only those with events")
    family_options(so)
    so.set_defaults(func=_soak)
