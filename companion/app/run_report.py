"""`uavsearch run`'s end: the flown run scored against the mission's ground truth, its files and figures."""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import msgspec
import numpy as np

from companion.app.evaluation import (
    CompanionLogs,
    FlightReport,
    evaluate,
    failed_criteria,
    flight_report,
    read_approach,
    read_target_logs,
    read_vertical,
    truth_cells,
)
from companion.app.operator_files import export
from companion.app.operator_run import ExportError, load_picture
from companion.app.run_options import RunOptions
from companion.app.target_report import target_line, target_summary, write_target_summary
from companion.batch import plots, report
from companion.batch.engine import RunResult
from companion.batch.montecarlo import Summary
from companion.batch.report import StudySummary
from companion.contracts.mission import Mission
from companion.core.world import World


class FlownMeta(msgspec.Struct, frozen=True):
    """summary.json's "_meta" of a flown run.

    The mission, its seed, how it was flown, and what the companions refused
    (`refused_by_companions`)."""

    mission: str
    seed: int
    distributed: bool  # always: the batch engine's summaries have no such key
    lockstep: bool
    run: str
    refused: dict[str, int]


def refused_by_companions(out: Path, n: int) -> dict[str, int]:
    """What the companions refused, summed over them, by kind.

    What the companions refused, summed over them, by kind ("mesh forged bundle", "MAVLink bad
    signature", ...), from their reports (uav{i}.json)."""
    total: dict[str, int] = {}
    for i in range(n):
        try:
            refused = json.loads((out / f"uav{i}.json").read_text()).get("refused", {})
        except (OSError, ValueError):
            continue
        for where, kinds in refused.items():
            for kind, senders in kinds.items():
                key = f"{where} {kind}"
                total[key] = total.get(key, 0) + sum(senders.values())
    return total


def report_run(
    opts: RunOptions,
    mission: Mission,
    world: World,
    logs: CompanionLogs,
    seed: int,
    run: str,
    started: float,
    stopped: bool,
) -> int:
    """Score the run flown into `opts.out`, write its files and print its figures; the exit code.

    Score the run flown into `opts.out`, write its files and print its figures; the exit code
    (1: nothing flown, or the mission's pass criteria failed)."""
    out = opts.out
    approach = read_approach(out / "approach.csv")
    targets = truth_cells(out / "truth.json")
    target_log = read_target_logs(out, mission.n_uavs)
    result = evaluate(world, logs.logs, targets, time.monotonic() - started, seed, approach, target_log)
    if result.steps == 0:
        if stopped:
            print("stopped by a signal before any step was flown", file=sys.stderr)
        else:
            print(
                "error: no step was flown (see the companion and vehicle logs in the output directory)",
                file=sys.stderr,
            )
        return 1
    refused = refused_by_companions(out, mission.n_uavs)
    meta = FlownMeta(mission.name, seed, True, opts.lockstep, run, refused)
    summary = _write_results(opts, mission, world, result, meta)
    vertical = read_vertical(out / "approach.csv")  # the steps with a pair horizontally within R_s
    flight = flight_report(mission, out, logs.logs, vertical)
    (out / "tracking.json").write_text(json.dumps(msgspec.to_builtins(flight), indent=2) + "\n")
    if opts.view:
        print(f"replay the run with: uavsearch view --replay {out}", flush=True)
    failures = failed_criteria(world, result, out / "approach.csv")
    _print_figures(opts, mission, result, summary.algorithms[mission.algorithm.name], approach, vertical)
    confirmed = target_summary(result, target_log, mission.sensor.perfect)
    write_target_summary(out, confirmed)
    if not mission.sensor.perfect:
        print(target_line(confirmed))
    _print_tracking(opts, mission, flight, refused)
    (out / "criteria.json").write_text(
        json.dumps({"passed": not failures, "failures": failures}, indent=2) + "\n"
    )
    _write_operator_files(out)
    if failures:
        print("pass criteria FAILED: " + "; ".join(failures), file=sys.stderr)
        return 1
    print(f"pass criteria met; wrote {out}")
    if not mission.secured:
        print("this run was INSECURE (no [security] keys): see the warning at its start", flush=True)
    return 0


def _write_operator_files(out: Path) -> None:
    """The operator's files of the run (operator.geojson, operator.kml, sectors.plan), or a warning."""
    try:
        export(load_picture(out), out)
    except ExportError as exc:
        print(f"warning: no files for the operator: {exc}", file=sys.stderr)


def _write_results(
    opts: RunOptions, mission: Mission, world: World, result: RunResult, meta: FlownMeta
) -> StudySummary:
    """The batch engine's files and plots of the run; returns its summary (summary.json)."""
    out, name = opts.out, mission.algorithm.name
    summary = report.write_summary(out, {name: [result]}, meta)
    report.write_trajectories(out, {name: [result]})
    report.write_steps(out, {name: [result]})
    report.write_targets(out, {name: [result]})
    report.copy_mission(opts.mission_file, out)
    plots.plot_prior(out / "prior_cvt.png", world)
    starts: dict[str, np.ndarray] = {name: np.array([(v.x, v.y) for v in mission.vehicles])}
    plots.plot_trajectories(out / "trajectories.png", {name: world}, {name: result}, starts)
    plots.plot_uncertainty(out / "uncertainty.png", {name: [result]})
    plots.plot_found(out / "targets_found.png", {name: [result]})
    plots.plot_links(out / "links.png", result, mission.comms.safety)
    return summary


def _print_figures(
    opts: RunOptions,
    mission: Mission,
    result: RunResult,
    s: Summary,
    approach: dict[int, float],
    vertical: dict[int, float],
) -> None:
    """The run's search figures and its closest approaches, horizontal and in three dimensions."""
    print(
        f"{mission.name}: {result.steps} steps, targets found {int(np.sum(result.confirm_steps >= 0))}/"
        f"{len(result.target_cells)}, mean target time {s.mean_target_time:.1f}, "
        f"min lambda_2 {s.min_lambda2:.4f}, min distance {s.min_distance:.1f} m"
    )
    if not approach:
        return
    closest_flown = min(approach.values())
    source = "stand-alone camera, position streams" if opts.external else "simulator, physics rate"
    print(
        f"closest approach along the flown tracks ({source}): "
        f"{result.approach.min():.1f} m (R_s = {mission.comms.safety:g} m); "
        f"{result.separation_losses} steps within R_s; "
        f"{closest_flown:.1f} m over all it recorded (start-up and hand-over included)"
    )
    within = (
        f"{len(vertical)} steps had a pair within R_s horizontally, at least "
        f"{min(vertical.values()):.1f} m apart vertically"
        if vertical
        else "no pair came within R_s horizontally"
    )
    print(f"in three dimensions: {within}")


def _print_tracking(
    opts: RunOptions, mission: Mission, flight: FlightReport, refused: dict[str, int]
) -> None:
    """Plan against flight (tracking.json), and what a secured swarm's companions refused."""
    p, h = flight.position_m, flight.heading_deg
    if p.median is not None and p.p95 is not None and h.median is not None and h.p95 is not None:
        print(
            f"plan vs flight ({opts.mode}): position error median {p.median:.1f} m, p95 {p.p95:.1f} m; "
            f"heading error median {h.median:.1f} deg, p95 {h.p95:.1f} deg; "
            f"{flight.outside_fence} logged poses outside the fence"
        )
    if mission.secured and refused:
        kinds = ", ".join(f"{n} {kind}" for kind, n in sorted(refused.items()))
        print(f"secured run: the companions refused {kinds} (who sent them: companion*.log, uav*.json)")
