"""`uavsearch`: the project's command line."""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from companion.batch.executors import ClusterError
from companion.mission import MissionError, load_mission

if TYPE_CHECKING:
    from companion.batch.generate import Family


def _mc(args: argparse.Namespace) -> int:
    from companion.batch.executors import open_executor
    from companion.batch.experiments import compare
    from companion.batch.report import copy_mission

    mission = load_mission(args.mission)
    algorithms = [a.strip() for a in args.algorithms.split(",") if a.strip()]
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
        )
    copy_mission(Path(args.mission), Path(args.out))
    _print_summary(summary)
    print(f"wrote {args.out}/summary.json, runs.csv, curves.csv and plots")
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
    from companion.bench.cluster_bench import cluster_bench, format_cluster_bench

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

    def span(text: str, kind: type) -> tuple:
        lo, _, hi = text.partition("-")
        return kind(lo), kind(hi or lo)

    return Family(
        uavs=span(args.uavs, int),
        across=span(args.across, float),
        centres=span(args.centres, int),
        targets=span(args.targets, int),
        layouts=tuple(args.layouts.split(",")),
        modes=tuple(args.modes.split(",")),
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

    algorithms = tuple(a.strip() for a in args.algorithms.split(",") if a.strip())
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
    from sim_vehicles.camera_node import run

    return run(args)


def _sim_bench(args: argparse.Namespace) -> int:
    from sim_vehicles.bench import bench_main

    return bench_main(args.args)


def _companion_bench(args: argparse.Namespace) -> int:
    from companion.bench.companion_bench import bench_main

    return bench_main(args.args)


def _add_executor_arguments(parser: argparse.ArgumentParser) -> None:
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--workers", type=int, default=None, help="local processes (default: all cores)")
    where.add_argument(
        "--scheduler",
        default=None,
        metavar="tcp://HOST:PORT",
        help="run on the workers of this Dask scheduler instead of local processes (README: cluster)",
    )


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="uavsearch", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)

    mc = sub.add_parser("mc", help="Monte Carlo comparison of algorithms (the paper's Figures 8-10)")
    mc.add_argument("--mission", required=True)
    mc.add_argument("--algorithms", default="proposed,no-ta,pheromone")
    mc.add_argument("--runs", type=int, default=20)
    mc.add_argument("--steps", type=int, default=None, help="sampling moments per run (default: mission)")
    mc.add_argument("--seed", type=int, default=None, help="default: the mission's seed")
    mc.add_argument("--out", default="out/mc")
    _add_executor_arguments(mc)
    mc.add_argument("--save-trajectories", action="store_true")
    mc.add_argument("--quiet", action="store_true", help="no progress bar")
    mc.set_defaults(func=_mc)

    sw = sub.add_parser("sweep", help="sweep one algorithm parameter (the paper's Figure 11)")
    sw.add_argument("--mission", required=True)
    sw.add_argument("--param", default="n_g")
    sw.add_argument("--values", default="10,20,30,40,50,60,70,80,90")
    sw.add_argument("--runs", type=int, default=20)
    sw.add_argument("--steps", type=int, default=None)
    sw.add_argument("--seed", type=int, default=None)
    sw.add_argument("--out", default="out/sweep")
    _add_executor_arguments(sw)
    sw.add_argument("--quiet", action="store_true")
    sw.set_defaults(func=_sweep)

    be = sub.add_parser("bench", help="time per 1,000 sampling moments and Monte Carlo throughput")
    be.add_argument("--missions", nargs="+", default=[f"mission_files/scenario{i}.toml" for i in (1, 2, 3)])
    be.add_argument("--runs", type=int, default=3)
    be.add_argument("--steps", type=int, default=1000)
    be.add_argument("--seed", type=int, default=1)
    _add_executor_arguments(be)
    be.add_argument(
        "--study-runs", type=int, default=8, help="runs per mission and algorithm in the throughput"
    )
    be.add_argument("--json", default=None, help="also write the figures to this JSON file")
    be.set_defaults(func=_bench)

    cl = sub.add_parser(
        "cluster-bench", help="Monte Carlo throughput: local pool against a Dask cluster on loopback"
    )
    cl.add_argument("--missions", nargs="+", default=[f"mission_files/scenario{i}.toml" for i in (1, 2, 3)])
    cl.add_argument("--workers", default="1,2", help="worker counts, e.g. 1,2")
    cl.add_argument("--study-runs", type=int, default=20, help="runs per mission and algorithm")
    cl.add_argument("--steps", type=int, default=1000)
    cl.add_argument("--seed", type=int, default=1)
    cl.add_argument("--json", default=None, help="also write the rows to this JSON file")
    cl.set_defaults(func=_cluster_bench)

    def family_options(p: argparse.ArgumentParser) -> None:
        p.add_argument("--uavs", default="2-12", help="UAVs per mission (range)")
        p.add_argument("--across", default="800-4000", help="region size in metres (range)")
        p.add_argument("--centres", default="1-6", help="distribution centres of eq. 1 (range)")
        p.add_argument("--targets", default="5-20", help="targets (range)")
        p.add_argument("--layouts", default="edge,clustered", help="start layouts")
        p.add_argument("--modes", default="grid,continuous", help="kinematics modes")
        p.add_argument("--steps", type=int, default=1000, help="sampling moments per run")

    ge = sub.add_parser("generate", help="write generated missions (a family beyond the scenario files)")
    ge.add_argument("--count", type=int, required=True)
    ge.add_argument("--seed", type=int, required=True)
    ge.add_argument("--out", required=True)
    family_options(ge)
    ge.set_defaults(func=_generate)

    so = sub.add_parser("soak", help="safety soak: separation and link events on generated missions")
    so.add_argument("--missions", type=int, default=20)
    so.add_argument("--seed", type=int, default=1)
    so.add_argument("--algorithms", default="proposed,no-ta,pheromone")
    so.add_argument("--loss", type=float, default=0.0, help="message loss probability on the radio")
    so.add_argument("--kill", action="store_true", help="one companion per mission dies mid-run")
    _add_executor_arguments(so)
    so.add_argument("--verbose", action="store_true", help="print every run, not only those with events")
    family_options(so)
    so.set_defaults(func=_soak)

    from companion.node.guidance import COMMAND_MODES

    co = sub.add_parser("companion", help="the companion process of one UAV (MAVLink + Zenoh mesh)")
    co.add_argument("--mission", required=True)
    co.add_argument("--uav", type=int, required=True, help="UAV index (0-based; MAVLink system id - 1)")
    co.add_argument(
        "--vehicle",
        default=None,
        help="pymavlink connection string (udp/udpin/udpout/tcp/serial); default: the simulator",
    )
    co.add_argument("--command-mode", choices=COMMAND_MODES, default="turn-rate")
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
    co.add_argument("--lockstep", action="store_true", help="step together with the simulator and the swarm")
    co.add_argument("--steps", type=int, default=None)
    co.add_argument("--seed", type=int, default=None)
    co.add_argument("--out", default=None, help="directory for the step log, the report and the .tlog")
    co.set_defaults(func=_companion)

    ru = sub.add_parser("run", help="simulator + one companion per UAV: a full simulated mission")
    ru.add_argument("mission")
    ru.add_argument("--speedup", type=float, default=10.0)
    ru.add_argument("--lockstep", action="store_true")
    ru.add_argument("--steps", type=int, default=None)
    ru.add_argument("--seed", type=int, default=None)
    ru.add_argument("--out", default="out/run")
    ru.add_argument(
        "--command-mode",
        choices=COMMAND_MODES,
        default=None,
        help="default: turn-rate on the bundled simulator, position-target on PX4 SITL, heading otherwise",
    )
    ru.add_argument("--flavour", choices=("ardupilot", "px4"), default=None)
    ru.add_argument(
        "--autopilot",
        choices=("bundled", "ardupilot-sitl", "px4-sitl"),
        default="bundled",
        help="the bundled simulator, or one ArduPlane or PX4 SITL per UAV at its start pose",
    )
    ru.add_argument(
        "--vehicles", default=None, help="fly vehicles that exist: one pymavlink URL per UAV, comma-separated"
    )
    ru.add_argument(
        "--camera-links", default=None, help="with --vehicles: links for the stand-alone simulated camera"
    )
    ru.add_argument(
        "--sitl-binary",
        default=None,
        help="ArduPlane SITL binary (default: $ARDUPLANE_SITL), PX4 bin/px4 (default: $PX4_SITL_DIR/bin/px4)",
    )
    ru.add_argument(
        "--sitl-instance", type=int, default=0, help="PX4: the first instance number tried (MAV_SYS_ID - 1)"
    )
    ru.add_argument(
        "--sitl-defaults", default=None, help="SITL parameter defaults (default: plane.parm by it)"
    )
    ru.add_argument("--quiet", action="store_true")
    ru.add_argument(
        "--keep-going", action="store_true", help="fly all the steps even when every target is found"
    )
    ru.add_argument("--view", action="store_true", help="serve the live map of the swarm (uavsearch view)")
    ru.add_argument("--view-port", type=int, default=0, help="the live map's port (0: any free port)")
    ru.set_defaults(func=_run)

    from companion.app.view.main import add_arguments as add_view_arguments

    vi = sub.add_parser("view", help="live map of a mission's swarm, or replay of a run, in the browser")
    add_view_arguments(vi)
    vi.set_defaults(func=_view)

    ro = sub.add_parser("router", help="a Zenoh router for client-mode meshes")
    ro.add_argument("--mission", default=None)
    ro.add_argument("--endpoint", default=None)
    ro.set_defaults(func=_router)

    from sim_vehicles.cli import add_arguments

    si = sub.add_parser("sim", help="the MAVLink fixed-wing simulator (all the mission's vehicles)")
    add_arguments(si)
    si.set_defaults(func=_sim)
    from sim_vehicles import camera_node

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
    return parser


PASSTHROUGH = {"sim-bench": _sim_bench, "companion-bench": _companion_bench}


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] in PASSTHROUGH:  # the benchmarks parse their own options
        return PASSTHROUGH[argv[0]](argparse.Namespace(args=argv[1:]))
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args))
    except MissionError as exc:
        print(f"error: mission file {exc}", file=sys.stderr)
        return 2
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except ClusterError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
