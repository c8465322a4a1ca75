"""The distributed engine: a real `dask scheduler` and two `dask worker` processes on loopback."""

from __future__ import annotations

import csv
import json
import os
import shutil
import signal
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import msgspec
import pytest

from companion.batch.engine import RunResult
from companion.batch.executors import ClusterError, DaskCluster
from companion.batch.montecarlo import execute, run_specs, specs_for, summarize
from companion.bench.loopback_cluster import LoopbackCluster, stop
from companion.core.feasibility import load_mission
from tests.cli import uavsearch

ROOT = Path(__file__).resolve().parents[2]
ALGORITHMS = ("proposed", "no-ta", "pheromone")
TIMING = {"seconds_per_1000_steps", "seconds"}  # compute times: the only fields allowed to differ


@pytest.fixture
def cluster(tmp_path: Path) -> Iterator[LoopbackCluster]:
    """A scheduler on loopback and two workers (one thread each, no nanny: killed, a worker stays dead)."""
    with LoopbackCluster(tmp_path) as cluster:
        for i in range(2):
            cluster.start_worker(f"worker{i}")
        yield cluster


def _ok(proc: subprocess.CompletedProcess[str]) -> None:
    assert proc.returncode == 0, proc.stderr


def _without_timing(summary: dict) -> dict:
    return {k: {f: v for f, v in s.items() if f not in TIMING} for k, s in summary.items()}


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open() as f:
        return [{k: v for k, v in row.items() if k not in TIMING} for row in csv.DictReader(f)]


@pytest.mark.slow
def test_mc_sweep_and_soak_on_the_cluster_equal_the_local_pool(
    cluster: LoopbackCluster, tmp_path: Path
) -> None:
    study = [
        "--mission",
        "mission_files/scenario1.toml",
        "--runs",
        "3",
        "--steps",
        "40",
        "--seed",
        "3",
        "--quiet",
    ]
    _ok(uavsearch("mc", *study, "--out", str(tmp_path / "local"), "--workers", "2"))
    _ok(uavsearch("mc", *study, "--out", str(tmp_path / "dask"), "--scheduler", cluster.address))
    local, dask = tmp_path / "local", tmp_path / "dask"
    summaries = [json.loads((d / "summary.json").read_text()) for d in (local, dask)]
    assert _without_timing(summaries[1]) == _without_timing(summaries[0])
    assert all(summaries[1][a]["runs"] == 3 for a in ALGORITHMS)
    assert _rows(dask / "runs.csv") == _rows(local / "runs.csv")
    assert (dask / "curves.csv").read_text() == (local / "curves.csv").read_text()
    executed = cluster.client.run(lambda dask_worker: dask_worker.state.executed_count)
    assert all(n > 0 for n in executed.values()), executed  # both workers computed runs

    sweep = [
        "--mission",
        "mission_files/scenario2.toml",
        "--values",
        "10,40",
        "--runs",
        "2",
        "--steps",
        "30",
        "--quiet",
    ]
    _ok(uavsearch("sweep", *sweep, "--out", str(local), "--workers", "2"))
    _ok(uavsearch("sweep", *sweep, "--out", str(dask), "--scheduler", cluster.address))
    local_points, dask_points = (json.loads((d / "sweep.json").read_text())["points"] for d in (local, dask))
    assert _without_timing(dict(enumerate(dask_points))) == _without_timing(dict(enumerate(local_points)))

    soak = ["soak", "--missions", "3", "--seed", "4", "--steps", "30", "--kill", "--verbose"]
    local_soak, dask_soak = (
        uavsearch(*soak, "--workers", "2"),
        uavsearch(*soak, "--scheduler", cluster.address),
    )
    assert local_soak.returncode in (0, 1), local_soak.stderr  # 1: a separation event (printed)
    assert (dask_soak.returncode, dask_soak.stdout) == (local_soak.returncode, local_soak.stdout)
    assert local_soak.stdout.count(" UAVs ") == 3 * 3  # every generated mission x algorithm, in order


def _summaries(results: list[RunResult], runs: int) -> dict:
    return _without_timing(
        {
            a: msgspec.to_builtins(summarize(results[i * runs : (i + 1) * runs]))
            for i, a in enumerate(ALGORITHMS)
        }
    )


@pytest.mark.slow
def test_a_worker_killed_mid_study_loses_no_run_and_counts_none_twice(cluster: LoopbackCluster) -> None:
    mission = load_mission(ROOT / "mission_files/scenario1.toml")
    runs = 8
    specs = specs_for(mission, ALGORITHMS, runs, 150, 11, lambda r: False)
    local = list(run_specs(specs, workers=2))

    victim, survivor = sorted(cluster.workers)
    arrived: list[tuple[int, RunResult]] = []
    in_progress_at_kill: tuple = ()
    executor = DaskCluster(cluster.address)
    try:
        for i, result in executor.imap_unordered(execute, specs):
            arrived.append((i, result))
            if len(arrived) >= 3 and cluster.workers[victim].poll() is None:
                deadline = time.monotonic() + 60
                while not in_progress_at_kill and time.monotonic() < deadline:
                    in_progress_at_kill = cluster.client.processing([victim])[victim]
                cluster.workers[victim].send_signal(signal.SIGKILL)
                cluster.workers[victim].wait(timeout=30)
    finally:
        executor.close()

    assert in_progress_at_kill, "the killed worker had no run in progress"
    assert list(cluster.client.nthreads()) == [survivor]
    assert sorted(i for i, _ in arrived) == list(range(len(specs)))  # every run, each exactly once
    for i, result in arrived:
        assert (result.algorithm, result.run) == (specs[i].mission.algorithm.name, specs[i].run)
    remote = [result for _, result in sorted(arrived, key=lambda pair: pair[0])]
    assert _summaries(remote, runs) == _summaries(local, runs)
    assert all(_summaries(remote, runs)[a]["runs"] == runs for a in ALGORITHMS)


@pytest.mark.slow
def test_a_scheduler_lost_mid_study_is_a_clear_error(cluster: LoopbackCluster) -> None:
    """Runs that came back are kept (a worker that dies after its result was gathered does not
    count); a scheduler that dies ends the study with the error, not a hang or a traceback."""
    specs = specs_for(
        load_mission(ROOT / "mission_files/scenario1.toml"), ["proposed"], 24, 60, 11, lambda r: False
    )
    arrived = 0
    executor = DaskCluster(cluster.address)
    try:
        with pytest.raises(ClusterError, match=f"lost the Dask scheduler at {cluster.address} mid-study"):
            for _ in executor.imap_unordered(execute, specs):
                arrived += 1
                if arrived == 1:
                    scheduler = cluster.procs[0]
                    scheduler.send_signal(signal.SIGKILL)
                    scheduler.wait(timeout=30)
    finally:
        executor.close()
    assert 1 <= arrived < len(specs)


def test_a_worker_with_other_code_is_refused(cluster: LoopbackCluster, tmp_path: Path) -> None:
    """A worker that would compute other results (here: a changed source file) stops the study,
    whether it joins after the study started or was there before."""
    other = tmp_path / "other"
    shutil.copytree(ROOT / "companion", other / "companion", ignore=shutil.ignore_patterns("__pycache__"))
    with (other / "companion/core/rhc.py").open("a") as f:
        f.write("# changed\n")
    specs = specs_for(
        load_mission(ROOT / "mission_files/scenario1.toml"), ["proposed"], 2, 5, 1, lambda r: False
    )
    executor = DaskCluster(cluster.address)
    try:
        for proc in cluster.workers.values():  # the late stranger gets every task
            stop(proc)
        stranger = cluster.start_worker("stranger", env=os.environ | {"PYTHONPATH": str(other)})
        refused = f"Dask workers {stranger} run other uavsearch code"
        with pytest.raises(ValueError, match=refused):
            list(executor.imap_unordered(execute, specs))
    finally:
        executor.close()
    with pytest.raises(ValueError, match=refused):
        DaskCluster(cluster.address)


def test_a_bad_scheduler_address_is_a_clear_error(tmp_path: Path) -> None:
    mission = ["--mission", "mission_files/scenario1.toml", "--runs", "1", "--steps", "5"]
    proc = uavsearch("mc", *mission, "--out", str(tmp_path), "--scheduler", "tcp://nowhere")
    assert proc.returncode == 2
    assert "--scheduler 'tcp://nowhere'" in proc.stderr and "port" in proc.stderr
    assert "Traceback" not in proc.stderr
