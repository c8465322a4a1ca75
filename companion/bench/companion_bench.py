"""Benchmark of the companion: step latency, and the largest swarm that keeps real time.

`uavsearch companion-bench` (or `bench_main(argv)`, or `python -m companion.bench`) measures the
step latency (observation in to command out) of a mission's UAVs stepping in lockstep, one worker
process each (`uav_worker`), again with a viewer attached (`--viewer`) or on a secured mesh
(`--secured`, with the signing cost per bundle); then the largest swarm that steps in real time
in peer and client mode (`trials.search`, the criterion `trials.realtime_verdict`).
Workers (`worker_pool`) are reused from trial to trial and stopped by PID; only 127.0.0.1 is
used. See docs/performance.md ("Companion").
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

import msgspec

from companion.bench.cpu_usage import MachineLoad, machine_load
from companion.bench.signing_cost import SigningCost, signing_cost
from companion.bench.swarm_missions import DEFAULT_MISSION, bench_mission
from companion.bench.trial_figures import SwarmSearch, TrialSummary
from companion.bench.trials import format_latency, search, summarize, trial
from companion.bench.uav_worker import viewer_main, worker_main
from companion.bench.worker_pool import Pool
from companion.contracts.arguments import HelpFormatter
from companion.contracts.mission import Mission
from companion.core.feasibility import load_mission


class CompanionBenchReport(msgspec.Struct, frozen=True, kw_only=True, omit_defaults=True):
    """Every figure of a run (`--json`); the parts left out (--skip-*, no --viewer/--secured) absent.

    `realtime` maps "mode@period" to that search."""

    machine: MachineLoad
    argv: list[str]
    latency: TrialSummary | None = None
    latency_with_viewer: TrialSummary | None = None
    latency_secured: TrialSummary | None = None
    signing_cost: SigningCost | None = None
    realtime: dict[str, SwarmSearch] | None = None
    elapsed_s: float


def _parser() -> argparse.ArgumentParser:
    """The options of `uavsearch companion-bench`."""
    parser = argparse.ArgumentParser(
        prog="uavsearch companion-bench",
        description="Companion step latency and the largest swarm that runs in real time.",
        formatter_class=HelpFormatter,
    )
    parser.add_argument("--mission", type=Path, default=DEFAULT_MISSION, help="the mission flown")
    parser.add_argument("--latency-steps", type=int, default=300, help="lockstep steps of the 4-UAV run")
    parser.add_argument("--sizes", default="4,10,20,30,50", help="swarm sizes tried, increasing")
    parser.add_argument("--modes", default="peer,client", help="mesh modes searched")
    parser.add_argument("--steps", type=int, default=20, help="steps per real-time trial")
    parser.add_argument("--period", type=float, help="real-time step period, s (default kinematics.step)")
    parser.add_argument(
        "--stress-period", type=float, default=0.0, help="also search at this faster period, s (0: no)"
    )
    parser.add_argument(
        "--default-runtime", action="store_true", help="do not set the lean ZENOH_RUNTIME for the UAVs"
    )
    parser.add_argument(
        "--viewer",
        action="store_true",
        help="repeat the latency run with a viewer attached (uavsearch view + headless Chromium)",
    )
    parser.add_argument(
        "--secured",
        action="store_true",
        help="repeat the latency run on a secured mesh (TLS, access control, signed bundles)",
    )
    parser.add_argument("--skip-latency", action="store_true", help="leave out the latency run")
    parser.add_argument("--skip-realtime", action="store_true", help="leave out the real-time swarm search")
    parser.add_argument("--json", type=Path, help="also write every figure to this file (default: none)")
    parser.add_argument("--quick", action="store_true", help="smoke run: tiny sizes and step counts")
    return parser


def _latency(pool: Pool, base: Mission, steps: int, tmp: Path, tag: str) -> TrialSummary:
    """The lockstep run of the mission's own UAVs on a peer mesh: its summary."""
    mission = bench_mission(base, None, "peer", f"{tag}lat")
    s = summarize(trial(pool, mission, steps, 0.0, tmp))
    print(
        f"step latency, observation in -> command out: {mission.n_uavs} UAVs of {base.name},"
        f" peer mesh, lockstep, {steps} steps",
        flush=True,
    )
    print("\n".join(format_latency(s)), flush=True)
    return s


def _latency_with_viewer(pool: Pool, base: Mission, steps: int, tmp: Path, tag: str) -> TrialSummary:
    """The lockstep run again with the view's live server (and a headless Chromium) on the mesh."""
    mission = bench_mission(base, None, "peer", f"{tag}latv")
    s = summarize(trial(pool, mission, steps, 0.0, tmp, viewer=True))
    v = s.viewer
    assert v is not None
    print(
        "the same with a viewer attached (uavsearch view's live server"
        f"{' + headless Chromium on its page' if v.browser else ''}):",
        flush=True,
    )
    print("\n".join(format_latency(s)), flush=True)
    print(
        f"  viewer: {v.cpu_ms_per_step:.2f} ms of CPU per step ({v.cores:.2f} cores),"
        f" {v.received} bundles received,"
        f" step {v.step} drawn last, {v.malformed} malformed, {v.late} late",
        flush=True,
    )
    return s


def _latency_secured(
    pool: Pool, base: Mission, steps: int, tmp: Path, tag: str
) -> tuple[TrialSummary, SigningCost]:
    """The lockstep run again on a secured mesh (keys made for it), and the signing cost per bundle."""
    from companion.contracts.keys import generate

    keys = tmp / "keys"
    generate(keys, base.n_uavs)
    mission = bench_mission(base, None, "peer", f"{tag}lats", keys)
    s = summarize(trial(pool, mission, steps, 0.0, tmp))
    print(
        "the same on a secured mesh (mutual TLS, access control, Ed25519-signed bundles"
        f" checked on receipt); {s.received} bundles received, {s.rejected} rejected:",
        flush=True,
    )
    print("\n".join(format_latency(s)), flush=True)
    cost = signing_cost(mission)
    print(
        f"  signing, per bundle of this swarm: sign {cost.seal_us_median:.0f} us, check"
        f" {cost.check_us_median:.0f} us (medians over {cost.bundles} bundles, one"
        " process, every UAV hearing every other)",
        flush=True,
    )
    return s, cost


def _realtime(
    pool: Pool,
    base: Mission,
    modes: list[str],
    sizes: list[int],
    steps: int,
    periods: list[float],
    tmp: Path,
    tag: str,
) -> dict[str, SwarmSearch]:
    """The largest real-time swarm of every mode at every period: {"mode@period": its search}."""
    found: dict[str, SwarmSearch] = {}
    for p in periods:
        for mode in modes:
            best, rows = search(pool, base, mode, sizes, steps, p, tmp, tag)
            found[f"{mode}@{p:g}"] = SwarmSearch(largest=best, trials=rows)
    print(
        "largest real-time swarm: " + ", ".join(f"{k}s {v.largest}" for k, v in found.items()),
        flush=True,
    )
    return found


def bench_main(argv: Sequence[str] | None = None) -> int:
    """`uavsearch companion-bench`: print the figures (and write them as JSON with --json)."""
    parser = _parser()
    args = parser.parse_args(argv)
    if args.quick:
        args.latency_steps, args.sizes, args.steps = 10, "2,3", 4
        args.period = args.period or 0.5
        args.stress_period = 0.0
    try:
        base = load_mission(args.mission)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    period = args.period or base.kinematics.step
    sizes = sorted(int(s) for s in args.sizes.split(","))
    modes = [m for m in args.modes.split(",") if m]
    if any(m not in ("peer", "client") for m in modes) or args.latency_steps < 2 or args.steps < 2:
        parser.error("modes are peer and/or client; at least 2 steps")
    load = machine_load()
    print(
        f"machine: {load.cores} cores, {load.busy_cores:.2f} cores busy before start"
        f" (load average {load.loadavg:.2f}); ZENOH_RUNTIME "
        f"{'default' if args.default_runtime else 'lean (1 app + 1 tx thread)'} in the UAV processes",
        flush=True,
    )
    latency = viewed = secured = None
    cost: SigningCost | None = None
    realtime: dict[str, SwarmSearch] | None = None
    pool = Pool(lean_runtime=not args.default_runtime)
    started = time.monotonic()
    try:
        with tempfile.TemporaryDirectory(prefix="companion-bench-") as tmp:
            tag = f"q{int(time.time()) % 100000}"
            steps = args.latency_steps
            if not args.skip_latency:
                latency = _latency(pool, base, steps, Path(tmp), tag)
                if args.viewer:
                    viewed = _latency_with_viewer(pool, base, steps, Path(tmp), tag)
                if args.secured:
                    secured, cost = _latency_secured(pool, base, steps, Path(tmp), tag)
            if not args.skip_realtime:
                periods = [period] + ([args.stress_period] if args.stress_period > 0 else [])
                realtime = _realtime(pool, base, modes, sizes, args.steps, periods, Path(tmp), tag)
    finally:
        pool.close()
    report = CompanionBenchReport(
        machine=load,
        argv=list(argv or []),
        latency=latency,
        latency_with_viewer=viewed,
        latency_secured=secured,
        signing_cost=cost,
        realtime=realtime,
        elapsed_s=time.monotonic() - started,
    )
    print(f"benchmark took {report.elapsed_s:.0f} s", flush=True)
    if args.json is not None:
        args.json.write_text(json.dumps(msgspec.to_builtins(report), indent=1) + "\n")
    return 0


def main() -> None:
    """`python -m companion.bench [worker | viewer] ...`."""
    if sys.argv[1:2] == ["worker"]:
        sys.exit(worker_main(sys.argv[2:]))
    if sys.argv[1:2] == ["viewer"]:
        sys.exit(viewer_main(sys.argv[2:]))
    sys.exit(bench_main(sys.argv[1:]))
