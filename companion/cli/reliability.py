"""`uavsearch fuzz` and `faults`: fuzzing campaigns and the fault matrix (docs/reliability.md)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from companion.cli.options import Subparsers
from companion.contracts.arguments import count, mission_argument, natural, step_count
from companion.core.feasibility import load_mission

FUZZ_NEEDS = (
    "error: uavsearch fuzz needs Hypothesis, which a plain install leaves out: pip install 'uavsearch[fuzz]'"
)


def _faults(args: argparse.Namespace) -> int:
    """`uavsearch faults`: the fault matrix's rows; exit 1 if any failed."""
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
    """`uavsearch fuzz`: the fuzzing campaigns; exit 1 if any failed."""
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


def register(sub: Subparsers) -> None:
    """Add `fuzz` and `faults` to the subcommands."""
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
