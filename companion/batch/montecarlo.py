"""Monte Carlo runner: many runs of the batch engine across a process pool, and their summary.

A run is a pure function of (mission, algorithm, seed, run index), so a `RunSpec` is all a worker
needs: the local process pool is the default executor, and any executor with `map` (a Dask or
Ray client's) can take the same specs.
"""

from __future__ import annotations

import math
import multiprocessing
import os
import signal
import threading
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import Executor
from dataclasses import dataclass
from types import FrameType

import numpy as np

from companion.batch.engine import RunResult, simulate
from companion.mission import Mission


@dataclass(frozen=True)
class RunSpec:
    """Everything that defines one run."""

    mission: Mission
    seed: int
    run: int
    steps: int
    record: bool = False
    kills: tuple[tuple[int, int], ...] = ()  # (uav, step its companion dies at): `simulate(kills=...)`


def execute(spec: RunSpec) -> RunResult:
    """Run one spec (top level, so that worker processes can import it)."""
    return simulate(spec.mission, spec.seed, spec.run, spec.steps, record=spec.record, kills=dict(spec.kills))


def specs_for(
    mission: Mission,
    algorithms: Iterable[str],
    runs: int,
    steps: int,
    seed: int,
    record: Callable[[int], bool],
    starts: Sequence[Mission] = (),
) -> list[RunSpec]:
    """One spec per (algorithm, run): run r of every algorithm sees the same targets and radio draws
    (and, given `starts`, flies the same start layout: the mission `starts[r]`)."""
    per_run = list(starts) or [mission] * runs
    if len(per_run) != runs:
        raise ValueError(f"{len(per_run)} start layouts for {runs} runs")
    return [
        RunSpec(per_run[r].with_algorithm(a), seed, r, steps, record(r))
        for a in algorithms
        for r in range(runs)
    ]


def _worker_init() -> None:
    """Workers leave SIGINT to the parent, which stops them (a Ctrl-C reaches the whole group)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _interrupt(_signum: int, _frame: FrameType | None) -> None:
    raise KeyboardInterrupt


def run_specs(
    specs: list[RunSpec], workers: int | None = None, executor: Executor | None = None
) -> Iterator[RunResult]:
    """Results in the order of `specs`, computed on `executor` or a local pool of `workers` processes.

    With the local pool, SIGTERM is turned into KeyboardInterrupt while it runs, and an interrupted
    study terminates its workers: no process is left behind.
    """
    workers = workers or os.cpu_count() or 1
    if executor is not None:
        yield from executor.map(execute, specs)
        return
    if workers == 1:
        yield from map(execute, specs)
        return
    chunk = max(1, min(8, len(specs) // (4 * workers)))
    pool = multiprocessing.get_context("spawn").Pool(workers, initializer=_worker_init)
    previous = (
        signal.signal(signal.SIGTERM, _interrupt)
        if threading.current_thread() is threading.main_thread()
        else None
    )
    try:
        yield from pool.imap(execute, specs, chunksize=chunk)
        pool.close()
    finally:
        pool.terminate()
        pool.join()
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


def ci95(values: np.ndarray) -> float:
    """Half-width of the normal 95 % confidence interval of the mean."""
    return float(1.96 * values.std(ddof=1) / math.sqrt(len(values))) if len(values) > 1 else 0.0


SUMMARY_KEYS = frozenset(
    {
        "runs",
        "mean_target_time",
        "targets_found_fraction",
        "final_mean_uncertainty",
        "min_lambda2",
        "min_distance",
        "seconds_per_1000_steps",
    }
)  # the keys every summary.json entry carries, batch engine and flown missions alike


def summarize(results: list[RunResult]) -> dict[str, float | int]:
    """The summary.json entry of one algorithm (SUMMARY_KEYS, plus confidence intervals and coverage)."""
    times = np.array([r.target_times().mean() if len(r.target_steps) else 0.0 for r in results])
    found = np.array([np.mean(r.target_steps >= 0) if len(r.target_steps) else 1.0 for r in results])
    final_unc = np.array([r.uncertainty[-1] for r in results])
    mean_unc = np.array([r.uncertainty.mean() for r in results])
    return {
        "runs": len(results),
        "steps": int(results[0].steps),
        "mean_target_time": float(times.mean()),
        "mean_target_time_ci95": ci95(times),
        "targets_found_fraction": float(found.mean()),
        "final_mean_uncertainty": float(final_unc.mean()),
        "final_mean_uncertainty_ci95": ci95(final_unc),
        "mean_uncertainty_over_run": float(mean_unc.mean()),
        "mean_uncertainty_over_run_ci95": ci95(mean_unc),
        "final_coverage": float(np.mean([r.coverage[-1] for r in results])),
        "min_lambda2": float(min(r.lambda2.min() for r in results)),
        "min_distance": float(min(r.min_distance.min() for r in results)),
        "seconds_per_1000_steps": float(np.mean([1000.0 * r.seconds / r.steps for r in results])),
    }
