"""`uavsearch bench`, `cluster-bench` and the benchmarks that parse their own options."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import msgspec

from companion.cli.options import Subparsers, add_executor_arguments
from companion.contracts.arguments import count, mission_argument, names, natural, sensor_pair, step_count
from companion.contracts.mission import ALGORITHMS
from companion.core.feasibility import load_mission

CLUSTER_NEEDS = (
    "error: uavsearch cluster-bench needs Dask distributed, which a plain install leaves out: "
    "pip install 'uavsearch[cluster]'"
)


DEFAULT_MISSIONS = [f"mission_files/scenario{i}.toml" for i in (1, 2, 3)]


def _bench(args: argparse.Namespace) -> int:
    """`uavsearch bench`: time per 1,000 steps and throughput, or CPU time against another checkout."""
    from companion.batch.executors import open_executor
    from companion.batch.experiments import bench, format_bench

    if args.against is not None:
        from companion.bench.against import cpu_against, format_against

        if args.missions is not None:
            raise SystemExit("bench: --missions with --against: each checkout flies its own scenario files")
        against = cpu_against(Path(args.against), args.rounds, args.steps, args.concurrent, args.sensor)
        print(format_against(against))
        return 0
    missions = [load_mission(m) for m in args.missions or DEFAULT_MISSIONS]
    if args.sensor is not None:
        from companion.batch.sensing_study import with_sensor

        missions = [with_sensor(m, *args.sensor) for m in missions]
    with open_executor(args.scheduler, args.workers) as executor:
        result = bench(
            missions, args.runs, args.steps, args.seed, study_runs=args.study_runs, executor=executor
        )
    print(format_bench(result))
    if args.json:
        Path(args.json).write_text(json.dumps(msgspec.to_builtins(result), indent=2) + "\n")
    return 0


def _cluster_bench(args: argparse.Namespace) -> int:
    """`uavsearch cluster-bench`: the local pool against a Dask cluster on loopback."""
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
        Path(args.json).write_text(json.dumps(msgspec.to_builtins(rows), indent=2) + "\n")
    return 0


def _sim_bench(args: argparse.Namespace) -> int:
    """`uavsearch sim-bench`: the simulator's capacity (its own options)."""
    from sim_vehicles.bench import bench_main

    return bench_main(args.args)


def _companion_bench(args: argparse.Namespace) -> int:
    """`uavsearch companion-bench`: companion step latency (its own options)."""
    from companion.bench.companion_bench import bench_main

    return bench_main(args.args)


def _altitude_bench(args: argparse.Namespace) -> int:
    """`uavsearch altitude-bench`: altitude-keeping error per flight phase (its own options)."""
    from companion.bench.altitude_bench import bench_main

    return bench_main(args.args)


def register(sub: Subparsers) -> None:
    """Add `bench` and `cluster-bench` to the subcommands."""
    be = sub.add_parser("bench", help="time per 1,000 sampling moments and Monte Carlo throughput")
    be.add_argument(
        "--missions",
        nargs="+",
        default=None,
        help=f"mission files (default: {' '.join(DEFAULT_MISSIONS)}; not with --against, which flies each "
        "checkout's own scenario files)",
    )
    be.add_argument(
        "--sensor",
        type=sensor_pair,
        default=None,
        help="PD,PF: every mission flown with this imperfect sensor, Pd flat (with --against too) "
        "(default: the files' sensors)",
    )
    be.add_argument("--runs", type=count, default=3, help="timed runs per mission and algorithm")
    be.add_argument("--steps", type=step_count, default=1000, help="sampling moments per run")
    be.add_argument("--seed", type=natural, default=1, help="the first run's seed")
    add_executor_arguments(be)
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


def _scaling_bench(args: argparse.Namespace) -> int:
    """`uavsearch scaling-bench`: CPU per step against the swarm's size, printed, plotted and saved."""
    from companion.bench.swarm_scaling import format_scaling, measure, plot_scaling

    sizes = [int(n) for n in args.sizes.split(",") if n.strip()]
    if not sizes or min(sizes) < 1:
        raise ValueError(f"--sizes {args.sizes!r}: give swarm sizes of at least 1, e.g. 4,8,16,32")
    result = measure(load_mission(args.mission), sizes, args.algorithms, args.steps)
    print(format_scaling(result))
    if args.out is not None:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        (out / "scaling.json").write_bytes(msgspec.json.format(msgspec.json.encode(result), indent=2) + b"\n")
        plot_scaling(result, out / "scaling.png")
        print(f"wrote {out / 'scaling.json'} and {out / 'scaling.png'}")
    return 0


def register_scaling(sub: Subparsers) -> None:
    """Add `scaling-bench` to the subcommands."""
    sc = sub.add_parser("scaling-bench", help="CPU per step of the batch engine against the swarm's size")
    mission_argument(sc, required=False, default="mission_files/scenario1.toml")
    sc.add_argument("--sizes", default="4,8,16,32", help="swarm sizes, e.g. 4,8,16,32")
    sc.add_argument("--algorithms", type=names(ALGORITHMS), default="proposed", help="e.g. proposed,no-ta")
    sc.add_argument("--steps", type=step_count, default=300, help="sampling moments per run")
    sc.add_argument(
        "--out", default=None, help="also write scaling.json and scaling.png here (default: none)"
    )
    sc.set_defaults(func=_scaling_bench)


def register_passthrough(sub: Subparsers) -> None:
    """Add the benchmarks that parse their own options (`PASSTHROUGH`)."""
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


PASSTHROUGH = {
    "sim-bench": _sim_bench,
    "companion-bench": _companion_bench,
    "altitude-bench": _altitude_bench,
}
