"""Scaling of the Monte Carlo engine: the local pool against a Dask cluster on loopback.

`uavsearch cluster-bench` runs the study mix of `uavsearch bench` (every mission x algorithm,
`study_runs` runs each) on a `LocalPool` of w processes and on a `LoopbackCluster` of w workers,
for each w of `--workers`, and reports runs per minute. The local pool's time includes starting
its processes, as in every study; the cluster's does not, its workers being long-lived (a warm-up
map loads their numba kernels first). For the cluster it also reports the CPU time per run of the
workers, the scheduler and this process (the client): what sizes a larger cluster
(docs/performance.md).
"""

from __future__ import annotations

import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

import msgspec

from companion.batch.executors import DaskCluster, LocalPool, RunExecutor
from companion.batch.montecarlo import RunSpec, execute
from companion.bench.loopback_cluster import LoopbackCluster
from companion.contracts.mission import ALGORITHMS, Mission


def study_mix(missions: Sequence[Mission], study_runs: int, steps: int, seed: int) -> list[RunSpec]:
    """Every mission x algorithm, `study_runs` runs each, interleaved as `uavsearch bench` does."""
    return [
        RunSpec(m.with_algorithm(a), seed, r, steps)
        for r in range(study_runs)
        for m in missions
        for a in ALGORITHMS
    ]


def _wall(executor: RunExecutor, specs: list[RunSpec]) -> float:
    started = time.perf_counter()
    for _ in executor.imap_unordered(execute, specs):
        pass
    return time.perf_counter() - started


class ScalingRow(msgspec.Struct, frozen=True, omit_defaults=True):
    """One executor and worker count (a row of `uavsearch cluster-bench --json`).

    The study mix's wall time and runs per minute; for Dask the CPU time per run of the workers (s),
    the scheduler and the client (ms); the runs per minute per worker against the first row's
    (`efficiency`)."""

    executor: str
    workers: int
    runs: int
    wall_seconds: float
    runs_per_minute: float
    worker_cpu_seconds_per_run: float | None = None
    scheduler_cpu_ms_per_run: float | None = None
    client_cpu_ms_per_run: float | None = None
    efficiency: float | None = None  # set by `cluster_bench` once the first row is in


def _row(kind: str, workers: int, runs: int, wall: float) -> ScalingRow:
    """A row from the wall time of `runs` runs."""
    return ScalingRow(kind, workers, runs, wall, 60 * runs / wall)


def measure_local(workers: int, specs: list[RunSpec]) -> ScalingRow:
    """The study mix on a local pool of `workers` processes, their start-up included."""
    return _row("local pool", workers, len(specs), _wall(LocalPool(workers), specs))


def measure_dask(workers: int, specs: list[RunSpec], directory: Path) -> ScalingRow:
    """The study mix on a loopback Dask cluster of `workers` warmed-up workers.

    With the CPU time per run of the workers, the scheduler and this process."""
    with LoopbackCluster(directory) as cluster:
        for i in range(workers):
            cluster.start_worker(f"worker{i}")
        executor = DaskCluster(cluster.address)
        try:
            _wall(executor, specs[: 2 * workers])  # warm-up: numba kernels loaded on every worker
            client = cluster.client
            before = (client.run(time.process_time), client.run_on_scheduler(time.process_time))
            own = time.process_time()
            wall = _wall(executor, specs)
            own = time.process_time() - own
            after = (client.run(time.process_time), client.run_on_scheduler(time.process_time))
        finally:
            executor.close()
    n = len(specs)
    worker_cpu = sum(after[0][w] - before[0][w] for w in after[0])
    return msgspec.structs.replace(
        _row("Dask", workers, n, wall),
        worker_cpu_seconds_per_run=worker_cpu / n,
        scheduler_cpu_ms_per_run=1000 * (after[1] - before[1]) / n,
        client_cpu_ms_per_run=1000 * own / n,
    )


def cluster_bench(
    missions: Sequence[Mission],
    workers: Sequence[int],
    study_runs: int = 20,
    steps: int = 1000,
    seed: int = 1,
) -> list[ScalingRow]:
    """One row per (executor, worker count), local pool and Dask interleaved.

    One row per (executor, worker count), local pool and Dask interleaved. `efficiency` is the
    runs per minute per worker against the first row's (the local pool of the first count)."""
    specs = study_mix(missions, study_runs, steps, seed)
    rows = []
    with tempfile.TemporaryDirectory(prefix="uavsearch-cluster-bench-") as tmp:
        for w in workers:
            rows.append(measure_local(w, specs))
            rows.append(measure_dask(w, specs, Path(tmp) / f"dask{w}"))
    base = rows[0].runs_per_minute / rows[0].workers
    return [msgspec.structs.replace(r, efficiency=r.runs_per_minute / r.workers / base) for r in rows]


def format_cluster_bench(rows: list[ScalingRow]) -> str:
    """The rows as the table `uavsearch cluster-bench` prints."""
    lines = [
        "executor    workers  runs  wall (s)  runs/min  efficiency"
        "  worker CPU s/run  scheduler ms/run  client ms/run"
    ]
    for r in rows:
        line = (
            f"{r.executor:<11} {r.workers:>7} {r.runs:>5} {r.wall_seconds:>9.1f} "
            f"{r.runs_per_minute:>9.0f} {r.efficiency:>11.2f}"
        )
        if r.worker_cpu_seconds_per_run is not None:
            line += (
                f" {r.worker_cpu_seconds_per_run:>17.3f} {r.scheduler_cpu_ms_per_run:>17.1f}"
                f" {r.client_cpu_ms_per_run:>14.1f}"
            )
        lines.append(line)
    return "\n".join(lines)
