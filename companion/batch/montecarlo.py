"""Monte Carlo runner: many runs of the batch engine on an executor, and their summary.

A run is a pure function of (mission, algorithm, seed, run index), so a `RunSpec` is all a worker
needs: the local process pool and a Dask cluster (`executors`) give the same results.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass

import msgspec
import numpy as np

from companion.batch.confirmation import confirm_time, never_confirmed
from companion.batch.engine import RunResult, simulate
from companion.batch.executors import LocalPool, RunExecutor, in_order
from companion.contracts.mission import Mission


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
    """One spec per (algorithm, run), with common random numbers across the algorithms.

    Run r of every algorithm sees the same targets and radio draws (and, given `starts`, flies the
    same start layout: the mission `starts[r]`).
    """
    per_run = list(starts) or [mission] * runs
    if len(per_run) != runs:
        raise ValueError(f"{len(per_run)} start layouts for {runs} runs")
    return [
        RunSpec(per_run[r].with_algorithm(a), seed, r, steps, record(r))
        for a in algorithms
        for r in range(runs)
    ]


def run_specs(
    specs: list[RunSpec],
    workers: int | None = None,
    executor: RunExecutor | None = None,
    on_result: Callable[[], object] | None = None,
) -> Iterator[RunResult]:
    """The results of `specs` in their order, each as soon as those before it are in.

    They are computed on `executor` (default: a `LocalPool` of `workers` processes); `on_result` is
    called as each run comes back, in whatever order.
    """
    executor = executor or LocalPool(workers)
    yield from in_order(executor.imap_unordered(execute, specs), len(specs), on_result)


def ci95(values: np.ndarray) -> float:
    """Half-width of the normal 95 % confidence interval of the mean."""
    return float(1.96 * values.std(ddof=1) / math.sqrt(len(values))) if len(values) > 1 else 0.0


class Summary(msgspec.Struct, frozen=True, omit_defaults=True):
    """The summary.json entry of one algorithm: its runs' mean metrics with 95 % half-widths (ci95)."""

    runs: int
    steps: int
    mean_target_time: float
    mean_target_time_ci95: float
    targets_found_fraction: float
    final_mean_uncertainty: float
    final_mean_uncertainty_ci95: float
    mean_uncertainty_over_run: float
    mean_uncertainty_over_run_ci95: float
    final_coverage: float
    min_lambda2: float
    min_distance: float
    closest_approach: float
    runs_with_event: int
    seconds_per_1000_steps: float
    # the share of the RHC's first choices the safety layer refused (docs/algorithm.md); absent: none
    first_choice_refused_share: float | None = None
    # chords that entered a no-fly zone inflated by the margin (`RunResult.keepout_entries`), summed
    # over the runs; absent when the region is convex and has no zones
    keepout_entries: int | None = None
    # an imperfect sensor's confirmations (`confirmation`): the mean time to a confirmed detection,
    # false confirmations and targets never confirmed per run; absent when every run's sensor was
    # perfect (then they are the first-sight metrics above)
    mean_confirm_time: float | None = None
    mean_confirm_time_ci95: float | None = None
    false_confirmations_per_run: float | None = None
    false_confirmations_per_run_ci95: float | None = None
    never_confirmed_per_run: float | None = None
    never_confirmed_per_run_ci95: float | None = None


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


def summarize(results: list[RunResult]) -> Summary:
    """The `Summary` of one algorithm's runs (SUMMARY_KEYS, plus confidence intervals and coverage)."""
    times = np.array([r.target_times().mean() if len(r.target_steps) else 0.0 for r in results])
    found = np.array([np.mean(r.target_steps >= 0) if len(r.target_steps) else 1.0 for r in results])
    final_unc = np.array([r.uncertainty[-1] for r in results])
    mean_unc = np.array([r.uncertainty.mean() for r in results])
    asked = sum(r.extras.get("first_choices", 0) for r in results)
    refused = sum(r.extras.get("first_choices_refused", 0) for r in results)
    entries = sum(r.keepout_entries or 0 for r in results)
    sensing = any(r.sensing is not None for r in results)
    confirm = np.array([confirm_time(r) for r in results])
    false = np.array([r.false_confirmations for r in results], dtype=float)
    never = np.array([never_confirmed(r) for r in results], dtype=float)
    return Summary(
        runs=len(results),
        steps=int(results[0].steps),
        mean_target_time=float(times.mean()),
        mean_target_time_ci95=ci95(times),
        targets_found_fraction=float(found.mean()),
        final_mean_uncertainty=float(final_unc.mean()),
        final_mean_uncertainty_ci95=ci95(final_unc),
        mean_uncertainty_over_run=float(mean_unc.mean()),
        mean_uncertainty_over_run_ci95=ci95(mean_unc),
        final_coverage=float(np.mean([r.coverage[-1] for r in results])),
        min_lambda2=float(min(r.lambda2.min() for r in results)),
        min_distance=float(min(r.min_distance.min() for r in results)),
        closest_approach=float(min(r.approach.min() for r in results)),
        runs_with_event=sum(r.separation_losses > 0 or r.link_losses > 0 for r in results),
        seconds_per_1000_steps=float(np.mean([1000.0 * r.seconds / r.steps for r in results])),
        first_choice_refused_share=float(refused / asked) if asked else None,
        keepout_entries=None if all(r.keepout_entries is None for r in results) else entries,
        mean_confirm_time=float(confirm.mean()) if sensing else None,
        mean_confirm_time_ci95=ci95(confirm) if sensing else None,
        false_confirmations_per_run=float(false.mean()) if sensing else None,
        false_confirmations_per_run_ci95=ci95(false) if sensing else None,
        never_confirmed_per_run=float(never.mean()) if sensing else None,
        never_confirmed_per_run_ci95=ci95(never) if sensing else None,
    )
