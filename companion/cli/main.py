"""`uavsearch`: the project's command line."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from companion.batch.executors import ClusterError
from companion.cli import area, bench, export, fly, generated, heldout, reliability, studies
from companion.cli.options import CommandParser
from companion.contracts.arguments import check_mission
from companion.contracts.entry import INTERRUPTED
from companion.contracts.lifeline import end_with_launcher
from companion.contracts.mission import MissionError

# each group adds its subcommands, in the order `uavsearch --help` lists them
GROUPS = (
    studies.register,
    bench.register,
    generated.register,
    heldout.register,
    reliability.register,
    fly.register,
    bench.register_scaling,
    bench.register_passthrough,
    area.register,
    export.register,
)


def build_parser() -> argparse.ArgumentParser:
    """The `uavsearch` parser: every group's subcommands, each with its handler (`func`)."""
    parser = argparse.ArgumentParser(prog="uavsearch", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True, parser_class=CommandParser)
    for register in GROUPS:
        register(sub)
    for command in sub.choices.values():  # a mistake prints the subcommand's own usage (`main`)
        command.set_defaults(parser=command)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run `uavsearch ARGV`; returns the exit code (2: a usage or mission file error)."""
    end_with_launcher()
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        if argv and argv[0] in bench.PASSTHROUGH:  # the benchmarks parse their own options
            return bench.PASSTHROUGH[argv[0]](argparse.Namespace(args=argv[1:]))
        args, extra = build_parser().parse_known_args(argv)
        if extra:  # the top-level parser would print its own usage
            args.parser.error(f"unrecognized arguments: {' '.join(extra)}")
        check_mission(args.parser, args)
        return int(args.func(args))
    except MissionError as exc:
        print(f"error: mission file {exc}", file=sys.stderr)
        return 2
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except (ClusterError, OSError) as exc:  # OSError: a path given that cannot be read or written
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return INTERRUPTED


if __name__ == "__main__":
    sys.exit(main())
