"""Options and parsers shared by the command groups: executors, start layouts, mission families."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING, Any, TypeAlias

from companion.batch.starts import LAYOUTS
from companion.contracts.arguments import HelpFormatter, count, names, real_span, step_count, whole_span
from companion.contracts.mission import (
    ALGORITHMS,
    MAX_CENTRES,
    MAX_GRID_CELLS,
    MAX_VEHICLES,
    MAX_ZONES,
    MODES,
)

if TYPE_CHECKING:
    from companion.batch.generate import Family

ACROSS_MAX = 20_000.0  # m: a generated region's grid (40 m cells) within the mission files' MAX_GRID_CELLS
ALGORITHM_LIST = f"comma-separated, of {', '.join(ALGORITHMS)}"


class CommandParser(argparse.ArgumentParser):
    """A subcommand's parser: every option's help shows its default (`HelpFormatter`)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("formatter_class", HelpFormatter)
        super().__init__(*args, **kwargs)


Subparsers: TypeAlias = "argparse._SubParsersAction[CommandParser]"


def random_starts_option(p: argparse.ArgumentParser) -> None:
    """Add `--random-starts [LAYOUTS]`: each run's start layout drawn anew."""
    p.add_argument(
        "--random-starts",
        nargs="?",
        const="edge,clustered",
        default=None,
        metavar="LAYOUTS",
        help="draw each run's start layout (edge,clustered by default), the same for every algorithm",
    )


def add_executor_arguments(parser: argparse.ArgumentParser) -> None:
    """Add `--workers N` or `--scheduler URL`: where the runs are computed."""
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--workers", type=count, default=None, help="local processes (default: one per core)")
    where.add_argument(
        "--scheduler",
        default=None,
        metavar="tcp://HOST:PORT",
        help="run on the workers of this Dask scheduler instead of local processes (README: cluster; "
        "default: none, the local pool)",
    )


def family_options(p: argparse.ArgumentParser) -> None:
    """Add the ranges of a generated mission family (`companion.batch.generate.Family`)."""
    p.add_argument(
        "--uavs", type=whole_span(1, MAX_VEHICLES), default="2-12", help="UAVs per mission (range)"
    )
    p.add_argument(
        "--across", type=real_span(1.0, ACROSS_MAX), default="800-4000", help="region size, m (range)"
    )
    p.add_argument(
        "--centres", type=whole_span(1, MAX_CENTRES), default="1-6", help="centres of eq. 1 (range)"
    )
    p.add_argument("--targets", type=whole_span(1, MAX_GRID_CELLS), default="5-20", help="targets (range)")
    p.add_argument("--layouts", type=names(LAYOUTS), default="edge,clustered", help="start layouts")
    p.add_argument("--modes", type=names(MODES), default="grid,continuous", help="kinematics modes")
    p.add_argument("--steps", type=step_count, default=1000, help="sampling moments per run")
    p.add_argument(
        "--zones", type=whole_span(0, MAX_ZONES), default="0-0", help="no-fly zones per mission (range)"
    )


def family(args: argparse.Namespace) -> Family:
    """The mission family of `generate`/`soak` from the command line's ranges."""
    from companion.batch.generate import Family

    return Family(
        uavs=args.uavs,
        across=args.across,
        centres=args.centres,
        targets=args.targets,
        layouts=args.layouts,
        modes=args.modes,
        steps=args.steps,
        zones=args.zones,
    )
