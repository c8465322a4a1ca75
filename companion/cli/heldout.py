"""`uavsearch evaluate` and `tune`: held-out missions, and the weights chosen on training ones."""

from __future__ import annotations

import argparse
import dataclasses
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import msgspec

from companion.cli.options import (
    Subparsers,
    add_executor_arguments,
    family,
    family_options,
    random_starts_option,
)
from companion.contracts.arguments import count, natural, weight
from companion.contracts.mission import ALGORITHMS, Mission

if TYPE_CHECKING:
    from companion.batch.heldout import DensityRow, Evaluation, OverallRow


def _output_folder(out: Path) -> None:
    """Make the output folder; a ValueError naming `--out` if it cannot be made."""
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ValueError(f"--out {out}: {exc.strerror or exc}") from None


def _missions(
    args: argparse.Namespace, out: Path, check: Callable[[int], object]
) -> tuple[list[Mission], dict]:
    """The missions of `evaluate`/`tune`, and how they were made.

    The missions of `evaluate`/`tune`: generated (written to out/missions/) or a folder's files,
    with the weights file applied; and how they were made. `check(n)` vets the command's other
    options for n missions before anything is generated or written."""
    from companion.batch.generate import generate, write
    from companion.batch.paired import apply_weights, load_missions, load_weights

    weights = [(path, load_weights(path)) for path in args.weights or ()]
    origin: dict
    if args.mission_dir is not None:
        missions, origin = load_missions(args.mission_dir), {"mission_dir": str(args.mission_dir)}
        check(len(missions))
        _output_folder(out)
    elif args.missions is not None and args.seed is not None:
        if args.missions < 1:
            raise ValueError("--missions must be at least 1")
        check(args.missions)
        mission_family = family(args)
        _output_folder(out)
        generated = generate(args.missions, args.seed, mission_family)
        write(generated, out / "missions")
        missions = [m for m, _ in generated]
        origin = {
            "generated": {
                "count": args.missions,
                "seed": args.seed,
                "family": dataclasses.asdict(mission_family),
            }
        }
    else:
        raise ValueError("give --missions N and --seed S (generated missions), or --mission-dir DIR")
    for path, table in weights:
        missions = [apply_weights(m, table, path) for m in missions]
    if weights:
        origin["weights"] = [{"file": path, "algorithm": table} for path, table in weights]
    return missions, origin


def _evaluate(args: argparse.Namespace) -> int:
    """`uavsearch evaluate`: the proposed method against each baseline on held-out missions."""
    from companion.batch.executors import open_executor
    from companion.batch.heldout import MIN_RUNS, evaluate
    from companion.batch.progress import run_progress
    from companion.batch.starts import parse_layouts

    def check(_: int) -> None:
        if args.runs < MIN_RUNS:
            raise ValueError(
                f"--runs must be at least {MIN_RUNS} (a per-mission interval needs two paired runs)"
            )

    out = Path(args.out)
    layouts = parse_layouts(args.random_starts) if args.random_starts else ()
    missions, origin = _missions(args, out, check)
    total = 3 * args.runs * len(missions)
    label = f"{len(missions)} missions x 3 algorithms x {args.runs} runs"
    with (
        open_executor(args.scheduler, args.workers) as executor,
        run_progress(total, label, not args.quiet) as advance,
    ):
        result = evaluate(missions, args.runs, args.steps, out, executor, layouts, origin, advance)
    _print_evaluation(result)
    print(f"wrote {out}/evaluate.json, missions.csv, overall.csv, runs.csv, evaluate(_density).png")
    return 0


def _tune(args: argparse.Namespace) -> int:
    """`uavsearch tune`: the weights chosen on training missions (Optuna)."""
    from companion.batch.executors import open_executor
    from companion.batch.progress import run_progress
    from companion.batch.starts import parse_layouts
    from companion.batch.tune import SPACE, Setup, load_space, plan, select, tune

    out = Path(args.out)
    layouts = parse_layouts(args.random_starts) if args.random_starts else ()
    space = load_space(args.space) if args.space else SPACE
    params = [p.strip() for p in args.params.split(",") if p.strip()] if args.params else None
    chosen = select(space, args.algorithm, params)
    if args.confirm < 0:
        raise ValueError("--confirm must be at least 0")
    missions, origin = _missions(args, out, lambda n: plan(args.budget, n, args.runs, args.confirm))
    seed = args.seed if args.seed is not None else 0
    setup = Setup(
        args.algorithm,
        args.runs,
        args.steps,
        args.budget,
        seed,
        args.uncertainty_weight,
        layouts,
        args.confirm,
    )
    trials, total = plan(args.budget, len(missions), args.runs, args.confirm)
    label = f"tune {args.algorithm}: {trials} trials x {len(missions)} missions x {args.runs} runs"
    with (
        open_executor(args.scheduler, args.workers, keep=True) as executor,
        run_progress(total, label, not args.quiet) as advance,
    ):
        tune(missions, chosen, setup, out, executor, origin, advance)
    print((out / "weights.toml").read_text(), end="")
    print(f"wrote {out}/weights.toml, history.csv, study.json and tune.png")
    return 0


def _print_evaluation(result: Evaluation) -> None:
    """The evaluation's tables: per mission, overall, and by area per UAV."""
    from rich.console import Console
    from rich.table import Table

    def interval(row: msgspec.Struct, key: str, scale: float = 1.0, digits: int = 4) -> str:
        v, lo, hi = (scale * getattr(row, k) for k in (key, f"{key}_low", f"{key}_high"))
        return f"{v:.{digits}g} [{lo:.{digits}g}, {hi:.{digits}g}]"

    console = Console(width=max(Console().width, 150))  # wide enough when piped to a file
    per = Table(title="per mission: proposed - baseline, mean over paired runs [95 % CI]")
    per.add_column("mission")
    per.add_column("UAVs", justify="right")
    keys = list(dict.fromkeys((r.baseline, r.metric) for r in result.missions))
    for baseline, metric in keys:
        per.add_column(f"{metric} vs {baseline}", justify="right")
    info = {i.mission: i for i in result.mission_info}
    for name, i in info.items():
        cells = {(r.baseline, r.metric): r for r in result.missions if r.mission == name}
        per.add_row(name, str(i.uavs), *(interval(cells[k], "difference", digits=3) for k in keys))
    console.print(per)
    overall = Table(title=f"overall ({result.meta.missions} missions x {result.meta.runs} runs)")
    halves = Table(title="by area per UAV: dense and thin halves of the missions")
    for table, column in ((overall, "relative (%)"), (halves, "km2 per UAV")):
        for col in ("baseline", "metric", column, "mean difference [95 % CI]", "win rate [Wilson 95 %]"):
            table.add_column(col, justify="right")
    rows: list[tuple[Table, OverallRow | DensityRow, str]] = [
        *((overall, r, interval(r, "relative_difference", 100, 3)) for r in result.overall),
        *((halves, r, r.km2_per_uav) for r in result.by_density),
    ]
    for table, r, cell in rows:
        wins = f"{r.wins}/{r.missions}: " + interval(r, "win_rate", 100, 3)
        table.add_row(r.baseline, r.metric, cell, interval(r, "difference"), wins)
    console.print(overall)
    console.print(halves)


def mission_set_options(p: argparse.ArgumentParser, out: str) -> None:
    """Add the options of a set of missions (generated or a folder's) and where to compute them."""
    p.add_argument("--missions", type=count, default=None, help="generate this many missions (default: none)")
    p.add_argument("--seed", type=natural, default=None, help="the generator's seed (default: none)")
    p.add_argument(
        "--mission-dir", default=None, help="use the mission files of a folder instead (default: none)"
    )
    p.add_argument(
        "--weights",
        nargs="+",
        default=None,
        metavar="FILE",
        help="TOML files whose [algorithm] tables replace the missions' weights, in order (default: the "
        "missions' own)",
    )
    p.add_argument("--out", default=out, help="output folder")
    add_executor_arguments(p)
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    family_options(p)


def register(sub: Subparsers) -> None:
    """Add `evaluate` and `tune` to the subcommands."""
    ev = sub.add_parser(
        "evaluate", help="the proposed method against each baseline on held-out missions (paired, with CIs)"
    )
    mission_set_options(ev, "out/evaluate")
    ev.add_argument("--runs", type=count, default=10, help="paired runs per mission and algorithm")
    random_starts_option(ev)
    ev.set_defaults(func=_evaluate)

    tu = sub.add_parser(
        "tune", help="choose the weights the paper does not give, on training missions (Optuna)"
    )
    mission_set_options(tu, "out/tune")
    tu.add_argument("--budget", type=count, required=True, help="runs in all, the current weights' included")
    tu.add_argument("--runs", type=count, default=1, help="runs per mission and candidate")
    tu.add_argument(
        "--algorithm", choices=ALGORITHMS, default="proposed", help="the algorithm whose weights are tuned"
    )
    tu.add_argument("--params", default=None, help="fields to tune (default: every row the algorithm reads)")
    tu.add_argument("--space", default=None, help="a TOML search space (default: companion.batch.tune.SPACE)")
    tu.add_argument(
        "--uncertainty-weight", type=weight, default=0.5, help="lambda: weight of the uncertainty term"
    )
    tu.add_argument(
        "--confirm",
        type=natural,
        default=5,
        help="best candidates flown again on fresh runs before one is chosen",
    )
    random_starts_option(tu)
    tu.set_defaults(func=_tune)
