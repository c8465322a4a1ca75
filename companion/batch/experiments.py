"""Studies built on the Monte Carlo runner: the algorithm comparison, parameter sweeps, benchmarks."""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import msgspec
import numpy as np

from companion.batch import plots, report
from companion.batch.engine import RunResult, simulate
from companion.batch.executors import LocalPool, RunExecutor
from companion.batch.montecarlo import RunSpec, Summary, execute, run_specs, specs_for, summarize
from companion.batch.progress import run_progress
from companion.batch.report import StudySummary
from companion.batch.starts import random_start
from companion.contracts.mission import ALGORITHMS, Mission
from companion.core.world import build_world


class CompareMeta(msgspec.Struct, frozen=True):
    """summary.json's "_meta" of a comparison: the mission, its seed, the runs and their starts."""

    mission: str
    seed: int
    runs: int
    steps: int
    algorithms: list[str]
    start_layouts: list[str] | str  # the layouts drawn from, or "the mission's"


class SweepPoint(msgspec.Struct, frozen=True):
    """One value of a swept parameter and the `Summary` of its runs."""

    param: str
    value: object  # the parameter's value, as JSON gives it
    summary: Summary

    def to_json(self) -> dict[str, object]:
        """sweep.json's point: the summary's fields, then the parameter's value under its name."""
        return {**msgspec.to_builtins(self.summary), self.param: self.value}


class Sweep(msgspec.Struct, frozen=True):
    """sweep.json: the swept parameter and one point per value."""

    param: str
    points: list[SweepPoint]

    def to_json(self) -> dict[str, object]:
        """sweep.json's content."""
        return {"param": self.param, "points": [p.to_json() for p in self.points]}


class AlgorithmTime(msgspec.Struct, frozen=True):
    """`bench`: one mission and algorithm's compute time on one core, with the sensor it flew.

    `pd`, `pd_edge` and `pf`: the mission's detector (`Sensor`; 1, 1, 0 the paper's camera)."""

    mission: str
    algorithm: str
    seconds_per_1000_steps: float
    pd: float
    pd_edge: float
    pf: float


class Throughput(msgspec.Struct, frozen=True):
    """`bench`: the Monte Carlo throughput on the study's mix of missions and algorithms."""

    workers: int
    executor: str
    runs: int
    steps: int
    wall_seconds: float
    startup_seconds: float
    runs_per_minute: float


class Bench(msgspec.Struct, frozen=True):
    """`bench`'s result (what `uavsearch bench --json` writes)."""

    per_algorithm: list[AlgorithmTime]
    throughput: Throughput
    study_estimate_minutes: float
    study_definition: str


def run_all(specs: list[RunSpec], executor: RunExecutor, progress: bool, label: str) -> list[RunResult]:
    """Run the specs on the executor with progress fed as runs come back; results in spec order."""
    with run_progress(len(specs), f"{label} on {executor.description}", progress) as advance:
        return list(run_specs(specs, executor=executor, on_result=advance))


def compare(
    mission: Mission,
    algorithms: Sequence[str],
    runs: int,
    steps: int,
    seed: int,
    out: Path,
    workers: int | None = None,
    save_trajectories: bool = False,
    progress: bool = True,
    executor: RunExecutor | None = None,
    layouts: tuple[str, ...] = (),
) -> StudySummary:
    """The paper's comparison (Figures 8-10): every algorithm on the same mission instances.

    The paper's comparison (Figures 8-10): every algorithm on the same mission instances, computed
    on `executor` (default: a local pool of `workers` processes). With `layouts`, run r starts from
    the layout `starts.random_start` draws for it (starts.csv), the same for every algorithm; else
    from the mission's. Returns what summary.json holds (`report.write_summary`)."""
    for a in algorithms:
        if a not in ALGORITHMS:
            raise ValueError(f"unknown algorithm {a!r}; choose from {', '.join(ALGORITHMS)}")
    out.mkdir(parents=True, exist_ok=True)
    record: Callable[[int], bool] = lambda r: save_trajectories or runs == 1 or r == 0  # noqa: E731
    drawn = [random_start(mission, seed, r, layouts) for r in range(runs)] if layouts else []
    if drawn:
        report.write_starts(out, drawn)
        mission = drawn[0][0]  # the plots show run 0, from its own start
    specs = specs_for(mission, algorithms, runs, steps, seed, record, [m for m, _ in drawn])
    flat = run_all(specs, executor or LocalPool(workers), progress, f"{mission.name}: {len(specs)} runs")
    results = {a: flat[i * runs : (i + 1) * runs] for i, a in enumerate(algorithms)}
    meta = CompareMeta(mission.name, seed, runs, steps, list(algorithms), list(layouts) or "the mission's")
    summary = report.write_summary(out, results, meta)
    report.write_runs(out, results)
    report.write_curves(out, results)
    report.write_targets(out, results)
    if save_trajectories or runs == 1:
        recorded = {a: [r for r in rs if r.trajectory is not None] for a, rs in results.items()}
        report.write_trajectories(out, recorded)
        report.write_steps(out, recorded)
    worlds = {a: build_world(mission.with_algorithm(a), seed, 0) for a in algorithms}
    plots.plot_prior(out / "prior_cvt.png", build_world(mission.with_algorithm("proposed"), seed, 0))
    plots.plot_trajectories(out / "trajectories.png", worlds, {a: results[a][0] for a in algorithms})
    plots.plot_uncertainty(out / "uncertainty.png", results)
    plots.plot_found(out / "targets_found.png", results)
    plots.plot_pos(out / "pos.png", results)
    return summary


def _set_param(mission: Mission, param: str, value: str) -> Mission:
    """A copy of the mission with one algorithm weight changed (validated by the mission schema)."""
    raw = msgspec.to_builtins(mission)
    if param not in raw["algorithm"]:
        raise ValueError(f"unknown algorithm parameter {param!r}")
    try:
        raw["algorithm"][param] = json.loads(value)
        return msgspec.convert(raw, Mission)
    except ValueError as exc:  # JSONDecodeError, msgspec.ValidationError
        raise ValueError(f"--values: {param} = {value}: {exc}") from None


def sweep(
    mission: Mission,
    param: str,
    values: Sequence[str],
    runs: int,
    steps: int,
    seed: int,
    out: Path,
    workers: int | None = None,
    progress: bool = True,
    executor: RunExecutor | None = None,
) -> Sweep:
    """Figure 11: the proposed algorithm's metrics against one parameter (n_g by default).

    Figure 11: the proposed algorithm's metrics against one parameter (n_g by default), computed
    on `executor` (default: a local pool of `workers` processes). Returns what sweep.json holds:
    each value's `Summary`."""
    out.mkdir(parents=True, exist_ok=True)
    missions = [_set_param(mission.with_algorithm("proposed"), param, v) for v in values]
    specs = [RunSpec(m, seed, r, steps) for m in missions for r in range(runs)]
    flat = run_all(specs, executor or LocalPool(workers), progress, f"{mission.name}: sweep {param}")
    summaries = [summarize(flat[i * runs : (i + 1) * runs]) for i in range(len(values))]
    points = [SweepPoint(param, json.loads(v), s) for s, v in zip(summaries, values, strict=True)]
    result = Sweep(param, points)
    (out / "sweep.json").write_text(json.dumps(result.to_json(), indent=2) + "\n")
    plots.plot_sweep(
        out / f"sweep_{param}.png", param, [json.loads(v) for v in values], summaries, mission.comms.safety
    )
    return result


def bench(
    missions: Sequence[Mission],
    runs: int = 3,
    steps: int = 1000,
    seed: int = 1,
    workers: int | None = None,
    study_runs: int = 8,
    executor: RunExecutor | None = None,
) -> Bench:
    """Compute time per 1,000 sampling moments (Table 2 setting) and Monte Carlo throughput.

    Throughput is timed on the study's own mix: every mission x algorithm, `study_runs` runs each,
    on `executor` (default: a local pool of `workers` processes). The whole-study estimate (every
    mission x algorithm, 1,000 runs of 1,000 steps: the paper's study for its three scenarios) is
    the executor's start-up (until the first `executor.workers` results are in) plus the steady
    per-run time after it times the remaining runs.
    """
    rows = []
    for mission in missions:
        for a in ALGORITHMS:
            m = mission.with_algorithm(a)
            simulate(m, seed, 0, 5)  # compile numba kernels and warm caches outside the timing
            secs = [simulate(m, seed, r, steps).seconds for r in range(runs)]
            sensor = mission.sensor
            edge = sensor.pd if sensor.pd_edge is None else sensor.pd_edge
            seconds = 1000 * float(np.mean(secs)) / steps
            rows.append(AlgorithmTime(mission.name, a, seconds, sensor.pd, edge, sensor.pf))
    executor = executor or LocalPool(workers)
    workers = executor.workers
    specs = [
        RunSpec(mission.with_algorithm(a), seed, r, steps)
        for r in range(study_runs)
        for mission in missions
        for a in ALGORITHMS
    ]
    n = len(specs)
    started = time.perf_counter()
    arrivals = []
    for _ in executor.imap_unordered(execute, specs):
        arrivals.append(time.perf_counter() - started)
    first = min(workers, n - 1)
    per_run = (arrivals[-1] - arrivals[first - 1]) / (n - first)  # steady state, all workers busy
    study_runs_total = len(missions) * len(ALGORITHMS) * 1000
    study = arrivals[first - 1] + per_run * (study_runs_total - first) * 1000 / steps
    throughput = Throughput(
        workers, executor.description, n, steps, arrivals[-1], arrivals[first - 1], 60.0 / per_run
    )
    definition = (
        f"{len(missions)} mission{'s' * (len(missions) != 1)} x {len(ALGORITHMS)} "
        f"algorithms x 1,000 runs x 1,000 steps, on {executor.description}"
    )
    return Bench(rows, throughput, study / 60.0, definition)


def format_bench(result: Bench) -> str:
    """`bench`'s result as the lines `uavsearch bench` prints."""
    lines = ["mission     algorithm    s / 1,000 steps (one core)  sensor"]
    for r in result.per_algorithm:
        lines.append(f"{r.mission:<11} {r.algorithm:<12} {r.seconds_per_1000_steps:<27.3f} {_sensor_text(r)}")
    t = result.throughput
    lines.append(
        f"Monte Carlo throughput (study mix): {t.runs_per_minute:.1f} runs of {t.steps} steps per "
        f"minute on {t.executor} ({t.runs} runs in {t.wall_seconds:.1f} s, "
        f"{t.startup_seconds:.1f} s until the first {t.workers} finished)"
    )
    lines.append(
        f"whole study, {result.study_definition} (estimate): {result.study_estimate_minutes:.1f} min"
    )
    return "\n".join(lines)


def _sensor_text(row: AlgorithmTime) -> str:
    """'perfect', or Pd (under the UAV to the edge of the view) and Pf."""
    if row.pd == row.pd_edge == 1.0 and row.pf == 0.0:
        return "perfect"
    pd = f"{row.pd:g}" if row.pd == row.pd_edge else f"{row.pd:g}-{row.pd_edge:g}"
    return f"Pd {pd}, Pf {row.pf:g}"


def sweep_values(text: str) -> list[str]:
    """'10,20,30' -> ['10', '20', '30'] (each parsed as JSON when applied)."""
    values = [v.strip() for v in text.split(",") if v.strip()]
    if not values:
        raise ValueError("--values needs at least one value")
    return values
