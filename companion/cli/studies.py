"""`uavsearch mc`, `targets`, `versus`, `sweep`, `sensing-study`: Monte Carlo studies on the batch engine."""

from __future__ import annotations

import argparse
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING

from companion.cli.options import ALGORITHM_LIST, Subparsers, add_executor_arguments, random_starts_option
from companion.contracts.arguments import count, fraction, mission_argument, names, natural, step_count
from companion.contracts.mission import ALGORITHMS
from companion.core.feasibility import load_mission

if TYPE_CHECKING:
    from companion.batch.montecarlo import Summary
    from companion.batch.report import StudySummary


def _mc(args: argparse.Namespace) -> int:
    """`uavsearch mc`: the algorithms compared over Monte Carlo runs of one mission."""
    from companion.batch.executors import open_executor
    from companion.batch.experiments import compare
    from companion.batch.report import copy_mission
    from companion.batch.starts import parse_layouts

    mission = load_mission(args.mission)
    layouts = parse_layouts(args.random_starts) if args.random_starts else ()
    algorithms = list(args.algorithms)
    seed = mission.seed if args.seed is None else args.seed
    steps = args.steps or mission.steps
    with open_executor(args.scheduler, args.workers) as executor:
        summary = compare(
            mission,
            algorithms,
            args.runs,
            steps,
            seed,
            Path(args.out),
            save_trajectories=args.save_trajectories,
            progress=not args.quiet,
            executor=executor,
            layouts=layouts,
        )
    copy_mission(Path(args.mission), Path(args.out))
    _print_summary(summary)
    starts = " and starts.csv" if layouts else ""
    print(f"wrote {args.out}/summary.json, runs.csv, curves.csv, plots (pos.png: the confirmations){starts}")
    return 0


def _print_summary(summary: StudySummary) -> None:
    """The Monte Carlo summary, one row per algorithm."""
    from rich.console import Console
    from rich.table import Table

    table = Table(title="Monte Carlo summary")
    zones = any(s.keepout_entries is not None for s in summary.algorithms.values())
    for col in (
        "algorithm",
        "runs",
        "mean target time",
        "found",
        "final uncertainty",
        "min lambda_2",
        "min distance (m)",
        "runs with an event",
        *(["keep-out entries"] if zones else []),
        "s / 1,000 steps",
    ):
        table.add_column(col, justify="right")
    for name, s in summary.algorithms.items():
        table.add_row(
            name,
            str(s.runs),
            f"{s.mean_target_time:.1f} ± {s.mean_target_time_ci95:.1f}",
            f"{100 * s.targets_found_fraction:.1f} %",
            f"{s.final_mean_uncertainty:.4f} ± {s.final_mean_uncertainty_ci95:.4f}",
            f"{s.min_lambda2:.4f}",
            f"{s.min_distance:.1f}",
            str(s.runs_with_event),
            *([str(s.keepout_entries or 0)] if zones else []),
            f"{s.seconds_per_1000_steps:.3f}",
        )
    Console().print(table)
    _print_confirmations(summary.algorithms)


def _print_confirmations(summaries: Mapping[str, Summary]) -> None:
    """An imperfect sensor's confirmations, one row per algorithm (nothing for a perfect sensor)."""
    from rich.console import Console
    from rich.table import Table

    if all(s.mean_confirm_time is None for s in summaries.values()):
        return
    table = Table(title="Confirmed detections (imperfect sensor; 95 % intervals)")
    for col in ("algorithm", "time to confirmation", "false confirmations / run", "never confirmed / run"):
        table.add_column(col, justify="right")
    for name, s in summaries.items():
        table.add_row(
            name,
            f"{s.mean_confirm_time or 0.0:.1f} ± {s.mean_confirm_time_ci95 or 0.0:.1f}",
            f"{s.false_confirmations_per_run or 0.0:.2f} ± {s.false_confirmations_per_run_ci95 or 0.0:.2f}",
            f"{s.never_confirmed_per_run or 0.0:.2f} ± {s.never_confirmed_per_run_ci95 or 0.0:.2f}",
        )
    Console().print(table)


def _versus(args: argparse.Namespace) -> int:
    """`uavsearch versus`: two `mc` outputs of the same runs, paired run by run."""
    from rich.console import Console
    from rich.table import Table

    from companion.batch.versus import compare

    changes = compare(Path(args.before), Path(args.after))
    table = Table(title=f"{args.after} against {args.before}, paired run by run (95 % intervals)")
    for col in (
        "algorithm",
        "runs",
        "mean target time",
        "change",
        "mean uncertainty",
        "change",
        "closest approach (m)",
        "runs with an event",
    ):
        table.add_column(col, justify="right", no_wrap=col == "algorithm")
    for c in changes:
        t, u = c.change["mean_target_time"], c.change["mean_uncertainty"]
        table.add_row(
            c.algorithm,
            str(c.runs),
            f"{c.before['mean_target_time']:.1f} -> {c.after['mean_target_time']:.1f}",
            f"{t.estimate:+.2f} [{t.low:+.2f}, {t.high:+.2f}]",
            f"{c.before['mean_uncertainty']:.4f} -> {c.after['mean_uncertainty']:.4f}",
            f"{u.estimate:+.4f} [{u.low:+.4f}, {u.high:+.4f}]",
            f"{c.closest[0]:.1f} -> {c.closest[1]:.1f}",
            f"{c.events[0]} -> {c.events[1]}",
        )
    Console().print(table)
    return 0


def _targets(args: argparse.Namespace) -> int:
    """`uavsearch targets`: first-seen steps of one algorithm against another, by distance."""
    from rich.console import Console
    from rich.table import Table

    from companion.batch.by_distance import DEFAULT_EDGES, targets_by_distance, write_csv

    out = Path(args.dir)
    for name in ("summary.json", "mission.toml", "targets.csv"):
        if not (out / name).is_file():
            raise ValueError(f"{out}: no {name} (the output folder of `uavsearch mc`)")
    try:
        edges = DEFAULT_EDGES if args.edges is None else [float(e) for e in args.edges.split(",")]
    except ValueError as exc:
        raise ValueError(f"--edges: {args.edges!r} is not a list of distances in metres") from exc
    bins = targets_by_distance(out, args.algorithm, args.baseline, edges)
    table = Table(title=f"{args.algorithm} - {args.baseline}: first-seen step by distance from the start")
    for col in (
        "distance (m)",
        "targets",
        args.algorithm,
        args.baseline,
        "difference [95 % CI] (runs)",
        "sooner / later",
    ):
        table.add_column(col, justify="right")
    for b in bins:
        d = b.difference
        high = "" if b.high >= 1e9 else f"{b.high:.0f}"
        table.add_row(
            f"{b.low:.0f}-{high}",
            str(b.targets),
            f"{b.mean_step:.1f}",
            f"{b.baseline_mean_step:.1f}",
            f"{d.estimate:+.1f} [{d.low:+.1f}, {d.high:+.1f}] ({d.n})",
            f"{b.sooner} / {b.later}",
        )
    Console().print(table)
    path = out / f"targets_by_distance_{args.algorithm}_{args.baseline}.csv"
    write_csv(path, bins)
    print(f"wrote {path}")
    return 0


def _sweep(args: argparse.Namespace) -> int:
    """`uavsearch sweep`: one algorithm parameter swept over its values."""
    from companion.batch.executors import open_executor
    from companion.batch.experiments import sweep, sweep_values

    mission = load_mission(args.mission)
    seed = mission.seed if args.seed is None else args.seed
    values = sweep_values(args.values)
    with open_executor(args.scheduler, args.workers) as executor:
        result = sweep(
            mission,
            args.param,
            values,
            args.runs,
            args.steps or mission.steps,
            seed,
            Path(args.out),
            progress=not args.quiet,
            executor=executor,
        )
    for p in result.points:
        s = p.summary
        print(
            f"{args.param}={p.value}: mean target time {s.mean_target_time:.1f}, "
            f"mean uncertainty {s.mean_uncertainty_over_run:.4f}, min lambda_2 {s.min_lambda2:.4f}, "
            f"min distance {s.min_distance:.1f} m"
        )
    return 0


PAPER_SCENARIOS = ",".join(f"mission_files/scenario{s}.toml" for s in (1, 2, 3))


def probabilities(text: str) -> tuple[float, ...]:
    """'1,0.9,0.7': one or more probabilities in [0, 1], distinct, in the order given."""
    values = tuple(fraction(v.strip()) for v in text.split(",") if v.strip())
    if not values or len(set(values)) != len(values):
        raise argparse.ArgumentTypeError(f"need distinct probabilities, comma-separated: {text!r}")
    return values


def _sensing_study(args: argparse.Namespace) -> int:
    """`uavsearch sensing-study`: the algorithms over a grid of Pd x Pf on each mission."""
    from rich.console import Console
    from rich.table import Table

    from companion.batch.executors import open_executor
    from companion.batch.sensing_report import study
    from companion.batch.sensing_study import Definition

    paths = [p.strip() for p in args.missions.split(",") if p.strip()]
    missions = [load_mission(p) for p in paths]
    steps = args.steps or max(m.steps for m in missions)
    definition = Definition(
        paths, list(args.pd), list(args.pf), list(args.algorithms), args.runs, steps, args.seed
    )
    with open_executor(args.scheduler, args.workers) as executor:
        result = study(missions, definition, Path(args.out), executor, progress=not args.quiet)
    table = Table(title="Proposed - baseline: time to a confirmed detection (paired, 95 % intervals)")
    for col in ("mission", "Pd", "Pf", "baseline", "runs", "proposed", "baseline's", "difference"):
        table.add_column(col, justify="right")
    for p in result.paired:
        table.add_row(
            p.mission, f"{p.pd:g}", f"{p.pf:g}", p.baseline, str(p.runs), f"{p.proposed:.1f}",
            f"{p.baseline_value:.1f}",
            f"{p.difference:+.1f} [{p.difference_low:+.1f}, {p.difference_high:+.1f}]",
        )  # fmt: skip
    Console().print(table)
    print(
        f"wrote {args.out}/summary.csv, paired.csv, pos_curves.csv, results_table.md, plots "
        "(pos_*.png, confirm_*.png) and cells/ (per-run rows; run again to resume)"
    )
    return 0


def register(sub: Subparsers) -> None:
    """Add `mc`, `targets`, `versus`, `sweep` and `sensing-study` to the subcommands."""
    mc = sub.add_parser("mc", help="Monte Carlo comparison of algorithms (the paper's Figures 8-10)")
    mission_argument(mc)
    mc.add_argument(
        "--algorithms",
        type=names(ALGORITHMS),
        default="proposed,no-ta,pheromone",
        help=f"algorithms to compare, {ALGORITHM_LIST}",
    )
    mc.add_argument("--runs", type=count, default=20, help="runs per algorithm")
    mc.add_argument(
        "--steps",
        type=step_count,
        default=None,
        help="sampling moments per run (default: the mission's steps)",
    )
    mc.add_argument(
        "--seed", type=natural, default=None, help="the first run's seed (default: the mission's seed)"
    )
    mc.add_argument("--out", default="out/mc", help="output folder")
    add_executor_arguments(mc)
    mc.add_argument("--save-trajectories", action="store_true", help="also write every run's trajectories")
    mc.add_argument("--quiet", action="store_true", help="no progress bar")
    random_starts_option(mc)
    mc.set_defaults(func=_mc)

    ta = sub.add_parser(
        "targets", help="which targets one algorithm finds sooner than another, by distance from the start"
    )
    ta.add_argument("dir", help="an `uavsearch mc` output folder")
    ta.add_argument("--algorithm", choices=ALGORITHMS, default="proposed", help="the algorithm measured")
    ta.add_argument(
        "--baseline", choices=ALGORITHMS, default="no-ta", help="the algorithm it is compared with"
    )
    ta.add_argument("--edges", help="distance bins' edges, metres, comma-separated (default: 400 m bins)")
    ta.set_defaults(func=_targets)

    vs = sub.add_parser(
        "versus", help="two `uavsearch mc` outputs of the same runs (two versions or settings), paired"
    )
    vs.add_argument("before", help="an `uavsearch mc` output folder")
    vs.add_argument("after", help="another, of the same mission, seed and runs")
    vs.set_defaults(func=_versus)

    sw = sub.add_parser("sweep", help="sweep one algorithm parameter (the paper's Figure 11)")
    mission_argument(sw)
    sw.add_argument("--param", default="n_g", help="the [algorithm] field swept")
    sw.add_argument("--values", default="10,20,30,40,50,60,70,80,90", help="its values, comma-separated")
    sw.add_argument("--runs", type=count, default=20, help="runs per value")
    sw.add_argument(
        "--steps", type=step_count, default=None, help="sampling moments per run (default: the mission's)"
    )
    sw.add_argument(
        "--seed", type=natural, default=None, help="the first run's seed (default: the mission's)"
    )
    sw.add_argument("--out", default="out/sweep", help="output folder")
    add_executor_arguments(sw)
    sw.add_argument("--quiet", action="store_true", help="no progress bar")
    sw.set_defaults(func=_sweep)

    ss = sub.add_parser(
        "sensing-study", help="the algorithms under imperfect sensing: a grid of Pd x Pf (issue 37)"
    )
    ss.add_argument("--missions", default=PAPER_SCENARIOS, help="mission files, comma-separated")
    ss.add_argument("--pd", type=probabilities, default="1,0.9,0.7", help="probabilities of detection")
    ss.add_argument("--pf", type=probabilities, default="0,0.01,0.05", help="false-alarm rates per look")
    ss.add_argument(
        "--algorithms", type=names(ALGORITHMS), default="proposed,no-ta,pheromone", help=ALGORITHM_LIST
    )
    ss.add_argument("--runs", type=count, default=20, help="runs per algorithm and cell")
    ss.add_argument(
        "--steps", type=step_count, default=None, help="sampling moments per run (default: the missions')"
    )
    ss.add_argument("--seed", type=natural, default=None, help="the runs' seed (default: each mission's)")
    ss.add_argument("--out", default="out/sensing", help="output folder (a study there is resumed)")
    add_executor_arguments(ss)
    ss.add_argument("--quiet", action="store_true", help="no progress bar")
    ss.set_defaults(func=_sensing_study)
