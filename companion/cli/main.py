"""`uavsearch`: the project's command line."""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from companion.batch.executors import ClusterError
from companion.batch.starts import LAYOUTS
from companion.cli import area
from companion.contracts.arguments import (
    HelpFormatter,
    check_mission,
    count,
    fraction,
    mission_argument,
    names,
    natural,
    port,
    positive,
    real_span,
    step_count,
    weight,
    whole_span,
)
from companion.contracts.entry import INTERRUPTED
from companion.contracts.lifeline import end_with_launcher
from companion.contracts.mission import (
    ALGORITHMS,
    MAX_CENTRES,
    MAX_GRID_CELLS,
    MAX_VEHICLES,
    MODES,
    Mission,
    MissionError,
)
from companion.core.feasibility import load_mission

FUZZ_NEEDS = (
    "error: uavsearch fuzz needs Hypothesis, which a plain install leaves out: pip install 'uavsearch[fuzz]'"
)
CLUSTER_NEEDS = (
    "error: uavsearch cluster-bench needs Dask distributed, which a plain install leaves out: "
    "pip install 'uavsearch[cluster]'"
)
ACROSS_MAX = 20_000.0  # m: a generated region's grid (40 m cells) within the mission files' MAX_GRID_CELLS

if TYPE_CHECKING:
    from companion.batch.generate import Family


def _mc(args: argparse.Namespace) -> int:
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
    print(f"wrote {args.out}/summary.json, runs.csv, curves.csv, plots{starts}")
    return 0


def _print_summary(summary: dict) -> None:
    from rich.console import Console
    from rich.table import Table

    table = Table(title="Monte Carlo summary")
    for col in (
        "algorithm",
        "runs",
        "mean target time",
        "found",
        "final uncertainty",
        "min lambda_2",
        "min distance (m)",
        "s / 1,000 steps",
    ):
        table.add_column(col, justify="right")
    for name, s in summary.items():
        if name.startswith("_"):
            continue
        table.add_row(
            name,
            str(s["runs"]),
            f"{s['mean_target_time']:.1f} ± {s['mean_target_time_ci95']:.1f}",
            f"{100 * s['targets_found_fraction']:.1f} %",
            f"{s['final_mean_uncertainty']:.4f} ± {s['final_mean_uncertainty_ci95']:.4f}",
            f"{s['min_lambda2']:.4f}",
            f"{s['min_distance']:.1f}",
            f"{s['seconds_per_1000_steps']:.3f}",
        )
    Console().print(table)


def _versus(args: argparse.Namespace) -> int:
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
    from companion.batch.executors import open_executor
    from companion.batch.experiments import sweep, sweep_values

    mission = load_mission(args.mission)
    seed = mission.seed if args.seed is None else args.seed
    values = sweep_values(args.values)
    with open_executor(args.scheduler, args.workers) as executor:
        points = sweep(
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
    for p in points:
        print(
            f"{args.param}={p[args.param]}: mean target time {p['mean_target_time']:.1f}, "
            f"mean uncertainty {p['mean_uncertainty_over_run']:.4f}, min lambda_2 {p['min_lambda2']:.4f}, "
            f"min distance {p['min_distance']:.1f} m"
        )
    return 0


def _bench(args: argparse.Namespace) -> int:
    from companion.batch.executors import open_executor
    from companion.batch.experiments import bench, format_bench

    if args.against is not None:
        from companion.bench.against import cpu_against, format_against

        print(format_against(cpu_against(Path(args.against), args.rounds, args.steps, args.concurrent)))
        return 0
    missions = [load_mission(m) for m in args.missions]
    with open_executor(args.scheduler, args.workers) as executor:
        result = bench(
            missions, args.runs, args.steps, args.seed, study_runs=args.study_runs, executor=executor
        )
    print(format_bench(result))
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=2) + "\n")
    return 0


def _cluster_bench(args: argparse.Namespace) -> int:
    try:
        from companion.bench.cluster_bench import cluster_bench, format_cluster_bench
    except ImportError as exc:
        if exc.name not in ("distributed", "dask"):
            raise
        print(CLUSTER_NEEDS, file=sys.stderr)
        return 1

    missions = [load_mission(m) for m in args.missions]
    try:
        workers = [int(w) for w in args.workers.split(",") if w.strip()]
    except ValueError:
        workers = []
    if not workers or min(workers) < 1:
        raise ValueError(f"--workers {args.workers!r}: give worker counts of at least 1, e.g. 1,2")
    rows = cluster_bench(missions, workers, args.study_runs, args.steps, args.seed)
    print(format_cluster_bench(rows))
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2) + "\n")
    return 0


def _family(args: argparse.Namespace) -> Family:
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
    )


def _generate(args: argparse.Namespace) -> int:
    from companion.batch.generate import generate, write

    paths = write(generate(args.count, args.seed, _family(args)), Path(args.out))
    print(f"wrote {len(paths)} missions to {args.out}/")
    return 0


def _soak(args: argparse.Namespace) -> int:
    from rich.console import Console

    from companion.batch.executors import open_executor
    from companion.batch.soak import soak, soak_specs

    algorithms = tuple(args.algorithms)
    specs = soak_specs(args.missions, args.seed, args.steps, algorithms, args.loss, args.kill, _family(args))
    console = Console(highlight=False)
    runs = events = 0
    with open_executor(args.scheduler, args.workers) as executor:
        for row in soak(specs, executor=executor):
            runs += 1
            events += not row.clean
            if args.verbose or row.separation_losses or row.link_losses:
                killed = f" killed {row.killed[0][0]}@{row.killed[0][1]}" if row.killed else ""
                console.print(
                    f"{row.mission} {row.mode} {row.uavs} UAVs {row.algorithm}{killed}: "
                    f"{row.separation_losses} separation, {row.link_losses} link events, "
                    f"closest approach {row.closest_approach:.1f} m, "
                    f"found {row.targets_found}/{row.targets}",
                    style=None if row.clean else "bold red",
                )
    what = "a separation event" if args.kill else "a separation or link event"
    print(f"{runs} runs of {args.missions} generated missions: {events} with {what}")
    return 1 if events else 0


def _output_folder(out: Path) -> None:
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ValueError(f"--out {out}: {exc.strerror or exc}") from None


def _missions(
    args: argparse.Namespace, out: Path, check: Callable[[int], object]
) -> tuple[list[Mission], dict]:
    """The missions of `evaluate`/`tune`: generated (written to out/missions/) or a folder's files,
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
        family = _family(args)
        _output_folder(out)
        generated = generate(args.missions, args.seed, family)
        write(generated, out / "missions")
        missions = [m for m, _ in generated]
        origin = {
            "generated": {"count": args.missions, "seed": args.seed, "family": dataclasses.asdict(family)}
        }
    else:
        raise ValueError("give --missions N and --seed S (generated missions), or --mission-dir DIR")
    for path, table in weights:
        missions = [apply_weights(m, table, path) for m in missions]
    if weights:
        origin["weights"] = [{"file": path, "algorithm": table} for path, table in weights]
    return missions, origin


def _evaluate(args: argparse.Namespace) -> int:
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


def _print_evaluation(result: dict) -> None:
    from rich.console import Console
    from rich.table import Table

    def interval(row: dict, key: str, scale: float = 1.0, digits: int = 4) -> str:
        v, lo, hi = (scale * row[k] for k in (key, f"{key}_low", f"{key}_high"))
        return f"{v:.{digits}g} [{lo:.{digits}g}, {hi:.{digits}g}]"

    console = Console(width=max(Console().width, 150))  # wide enough when piped to a file
    per = Table(title="per mission: proposed - baseline, mean over paired runs [95 % CI]")
    per.add_column("mission")
    per.add_column("UAVs", justify="right")
    keys = list(dict.fromkeys((r["baseline"], r["metric"]) for r in result["missions"]))
    for baseline, metric in keys:
        per.add_column(f"{metric} vs {baseline}", justify="right")
    info = {i["mission"]: i for i in result["mission_info"]}
    for name, i in info.items():
        cells = {(r["baseline"], r["metric"]): r for r in result["missions"] if r["mission"] == name}
        per.add_row(name, str(i["uavs"]), *(interval(cells[k], "difference", digits=3) for k in keys))
    console.print(per)
    overall = f"overall ({result['meta']['missions']} missions x {result['meta']['runs']} runs)"
    halves = "by area per UAV: dense and thin halves of the missions"
    for title, rows, column, cell in (
        (overall, result["overall"], "relative (%)", lambda r: interval(r, "relative_difference", 100, 3)),
        (halves, result["by_density"], "km2 per UAV", lambda r: r["km2_per_uav"]),
    ):
        table = Table(title=title)
        for col in ("baseline", "metric", column, "mean difference [95 % CI]", "win rate [Wilson 95 %]"):
            table.add_column(col, justify="right")
        for r in rows:
            wins = f"{r['wins']}/{r['missions']}: " + interval(r, "win_rate", 100, 3)
            table.add_row(r["baseline"], r["metric"], cell(r), interval(r, "difference"), wins)
        console.print(table)


def _faults(args: argparse.Namespace) -> int:
    from companion.app.faults import ROWS, Plan, run_row

    rows = ROWS if args.row == "all" else (args.row,)
    if not 0 < args.at < args.at + args.outage < args.steps:
        raise ValueError(f"--at {args.at} --outage {args.outage} must fit within --steps {args.steps}")
    mission = load_mission(args.mission)
    if args.victim >= mission.n_uavs:
        raise ValueError(f"--victim {args.victim}: the mission has UAVs 0..{mission.n_uavs - 1}")
    plan = Plan(args.steps, args.at, args.outage, args.victim)
    failed = 0
    for row in rows:
        o = run_row(row, mission, Path(args.out) / row, plan)
        failed += bool(o.failures)
        print(
            f"{row}: {'FAILED: ' + '; '.join(o.failures) if o.failures else 'kept everything'}; "
            f"{o.uavs} UAVs, {o.steps} steps, completed {o.completed}, detections {o.detections} "
            f"(lost {len(o.lost_detections)}), closest approach {o.closest_approach_m:.1f} m "
            f"({o.separation_losses} steps within R_s), converged {o.converged}, {o.seconds:.0f} s",
            flush=True,
        )
    print(f"wrote {args.out}/<row>/outcome.json")
    return 1 if failed else 0


def _fuzz(args: argparse.Namespace) -> int:
    try:
        from companion.app.fuzz import CAMPAIGNS, run_campaign
    except ImportError as exc:
        if exc.name != "hypothesis":
            raise
        print(FUZZ_NEEDS, file=sys.stderr)
        return 1

    names = CAMPAIGNS if args.campaign == "all" else (args.campaign,)
    failed = 0
    for name in names:
        c = run_campaign(name, args.count, args.seed)
        failed += bool(c.failures)
        reasons = ", ".join(f"{r} x{n}" for r, n in c.reasons.most_common(5))
        print(
            f"{name}: {c.inputs:,} inputs, {c.accepted:,} accepted, {c.rejected:,} rejected and counted, "
            f"{len(c.failures)} failures, {c.seconds:.0f} s" + (f"; top reasons: {reasons}" * bool(reasons)),
            flush=True,
        )
        for failure in c.failures[:10]:
            print(f"  FAILURE {failure}", flush=True)
        if c.notes:
            print(f"  {json.dumps(c.notes, default=str)}", flush=True)
    return 1 if failed else 0


def _companion(args: argparse.Namespace) -> int:
    from companion.node.main import run_companion

    return run_companion(args)


def _run(args: argparse.Namespace) -> int:
    from companion.app.launcher import RunOptions, run_mission

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
    from companion.app.view.main import run_view

    return run_view(args)


def _links(text: str | None) -> tuple[str, ...]:
    return tuple(u.strip() for u in (text or "").split(",") if u.strip())


def _router(args: argparse.Namespace) -> int:
    from companion.node.mesh import router_main

    argv = ["--endpoint", args.endpoint] if args.endpoint else []
    return router_main([*argv, *(["--mission", args.mission] if args.mission else [])])


def _sim(args: argparse.Namespace) -> int:
    from sim_vehicles.cli import run

    return run(args)


def _camera(args: argparse.Namespace) -> int:
    from companion.app.camera_node import run

    return run(args)


def _sim_bench(args: argparse.Namespace) -> int:
    from sim_vehicles.bench import bench_main

    return bench_main(args.args)


def _companion_bench(args: argparse.Namespace) -> int:
    from companion.bench.companion_bench import bench_main

    return bench_main(args.args)


def _altitude_bench(args: argparse.Namespace) -> int:
    from companion.bench.altitude_bench import bench_main

    return bench_main(args.args)


def _random_starts_option(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--random-starts",
        nargs="?",
        const="edge,clustered",
        default=None,
        metavar="LAYOUTS",
        help="draw each run's start layout (edge,clustered by default), the same for every algorithm",
    )


def _add_executor_arguments(parser: argparse.ArgumentParser) -> None:
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--workers", type=count, default=None, help="local processes (default: one per core)")
    where.add_argument(
        "--scheduler",
        default=None,
        metavar="tcp://HOST:PORT",
        help="run on the workers of this Dask scheduler instead of local processes (README: cluster; "
        "default: none, the local pool)",
    )


class _Parser(argparse.ArgumentParser):
    """A subcommand's parser: every option's help shows its default (`HelpFormatter`)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("formatter_class", HelpFormatter)
        super().__init__(*args, **kwargs)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="uavsearch", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    algorithms = f"comma-separated, of {', '.join(ALGORITHMS)}"

    mc = sub.add_parser("mc", help="Monte Carlo comparison of algorithms (the paper's Figures 8-10)")
    mission_argument(mc)
    mc.add_argument(
        "--algorithms",
        type=names(ALGORITHMS),
        default="proposed,no-ta,pheromone",
        help=f"algorithms to compare, {algorithms}",
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
    _add_executor_arguments(mc)
    mc.add_argument("--save-trajectories", action="store_true", help="also write every run's trajectories")
    mc.add_argument("--quiet", action="store_true", help="no progress bar")
    _random_starts_option(mc)
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
    _add_executor_arguments(sw)
    sw.add_argument("--quiet", action="store_true", help="no progress bar")
    sw.set_defaults(func=_sweep)

    be = sub.add_parser("bench", help="time per 1,000 sampling moments and Monte Carlo throughput")
    be.add_argument(
        "--missions",
        nargs="+",
        default=[f"mission_files/scenario{i}.toml" for i in (1, 2, 3)],
        help="mission files",
    )
    be.add_argument("--runs", type=count, default=3, help="timed runs per mission and algorithm")
    be.add_argument("--steps", type=step_count, default=1000, help="sampling moments per run")
    be.add_argument("--seed", type=natural, default=1, help="the first run's seed")
    _add_executor_arguments(be)
    be.add_argument(
        "--study-runs", type=count, default=8, help="runs per mission and algorithm in the throughput"
    )
    be.add_argument("--json", default=None, help="also write the figures to this JSON file (default: none)")
    be.add_argument(
        "--against",
        metavar="CHECKOUT",
        help="instead: CPU seconds per run of this checkout against another's (e.g. a git worktree of an "
        "older commit), interleaved, with their ratio (default: none)",
    )
    be.add_argument(
        "--rounds", type=count, default=2, help="with --against: interleaved rounds (the minimum is taken)"
    )
    be.add_argument(
        "--concurrent",
        action="store_true",
        help="with --against: time both checkouts at the same time, one per core, in each round (on a "
        "machine whose speed drifts, both then see the same drift)",
    )
    be.set_defaults(func=_bench)

    cl = sub.add_parser(
        "cluster-bench", help="Monte Carlo throughput: local pool against a Dask cluster on loopback"
    )
    cl.add_argument(
        "--missions",
        nargs="+",
        default=[f"mission_files/scenario{i}.toml" for i in (1, 2, 3)],
        help="mission files",
    )
    cl.add_argument("--workers", default="1,2", help="worker counts, e.g. 1,2")
    cl.add_argument("--study-runs", type=count, default=20, help="runs per mission and algorithm")
    cl.add_argument("--steps", type=step_count, default=1000, help="sampling moments per run")
    cl.add_argument("--seed", type=natural, default=1, help="the first run's seed")
    cl.add_argument("--json", default=None, help="also write the rows to this JSON file (default: none)")
    cl.set_defaults(func=_cluster_bench)

    def family_options(p: argparse.ArgumentParser) -> None:
        p.add_argument(
            "--uavs", type=whole_span(1, MAX_VEHICLES), default="2-12", help="UAVs per mission (range)"
        )
        p.add_argument(
            "--across", type=real_span(1.0, ACROSS_MAX), default="800-4000", help="region size, m (range)"
        )
        p.add_argument(
            "--centres", type=whole_span(1, MAX_CENTRES), default="1-6", help="centres of eq. 1 (range)"
        )
        p.add_argument(
            "--targets", type=whole_span(1, MAX_GRID_CELLS), default="5-20", help="targets (range)"
        )
        p.add_argument("--layouts", type=names(LAYOUTS), default="edge,clustered", help="start layouts")
        p.add_argument("--modes", type=names(MODES), default="grid,continuous", help="kinematics modes")
        p.add_argument("--steps", type=step_count, default=1000, help="sampling moments per run")

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
        help=f"algorithms, {algorithms}",
    )
    so.add_argument("--loss", type=fraction, default=0.0, help="message loss probability on the radio")
    so.add_argument("--kill", action="store_true", help="one companion per mission dies mid-run")
    _add_executor_arguments(so)
    so.add_argument("--verbose", action="store_true", help="print every run, not only those with events")
    family_options(so)
    so.set_defaults(func=_soak)

    def mission_set_options(p: argparse.ArgumentParser, out: str) -> None:
        p.add_argument(
            "--missions", type=count, default=None, help="generate this many missions (default: none)"
        )
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
        _add_executor_arguments(p)
        p.add_argument("--quiet", action="store_true", help="no progress bar")
        family_options(p)

    ev = sub.add_parser(
        "evaluate", help="the proposed method against each baseline on held-out missions (paired, with CIs)"
    )
    mission_set_options(ev, "out/evaluate")
    ev.add_argument("--runs", type=count, default=10, help="paired runs per mission and algorithm")
    _random_starts_option(ev)
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
    _random_starts_option(tu)
    tu.set_defaults(func=_tune)

    fz = sub.add_parser("fuzz", help="fuzzing campaigns: mesh, MAVLink, camera frames, mission files")
    fz.add_argument(
        "--campaign",
        default="all",
        choices=("all", "mesh", "mavlink", "camera", "mission"),
        help="which campaign",
    )
    fz.add_argument(
        "--count",
        type=count,
        default=None,
        help="inputs per campaign (default: 100,000 mesh, 10,000 others, 1,000 mission files)",
    )
    fz.add_argument("--seed", type=natural, default=0, help="the inputs' seed")
    fz.set_defaults(func=_fuzz)

    fa = sub.add_parser("faults", help="the fault matrix on real processes (docs/reliability.md)")
    fa.add_argument(
        "--row",
        default="all",
        choices=("all", "restart", "sim-restart", "link-loss", "partition", "loss"),
        help="which row of the matrix",
    )
    mission_argument(fa, required=False, default="mission_files/scenario1.toml")
    fa.add_argument("--steps", type=step_count, default=300, help="steps of each row's mission")
    fa.add_argument("--at", type=natural, default=60, help="the step the fault strikes at")
    fa.add_argument("--outage", type=count, default=8, help="steps the fault lasts (link-loss: 10 s)")
    fa.add_argument("--victim", type=natural, default=1, help="the UAV a companion or link fault hits")
    fa.add_argument("--out", default="out/faults", help="output folder")
    fa.set_defaults(func=_faults)

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
    sb = sub.add_parser(
        "sim-bench", help="simulator capacity: vehicles in real time, highest speedup", add_help=False
    )
    sb.add_argument("args", nargs=argparse.REMAINDER, help="passed to the benchmark (--help for its options)")
    sb.set_defaults(func=_sim_bench)
    cb = sub.add_parser(
        "companion-bench", help="companion step latency and the largest real-time swarm", add_help=False
    )
    cb.add_argument("args", nargs=argparse.REMAINDER, help="passed to the benchmark (--help for its options)")
    cb.set_defaults(func=_companion_bench)
    ab = sub.add_parser(
        "altitude-bench",
        help="altitude-keeping error per flight phase of ArduPlane SITL, PX4 SITL and the bundled simulator",
        add_help=False,
    )
    ab.add_argument("args", nargs=argparse.REMAINDER, help="passed to the benchmark (--help for its options)")
    ab.set_defaults(func=_altitude_bench)
    area.register(sub)
    for command in sub.choices.values():  # a mistake prints the subcommand's own usage (`main`)
        command.set_defaults(parser=command)
    return parser


PASSTHROUGH = {
    "sim-bench": _sim_bench,
    "companion-bench": _companion_bench,
    "altitude-bench": _altitude_bench,
}


def main(argv: Sequence[str] | None = None) -> int:
    end_with_launcher()
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        if argv and argv[0] in PASSTHROUGH:  # the benchmarks parse their own options
            return PASSTHROUGH[argv[0]](argparse.Namespace(args=argv[1:]))
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
