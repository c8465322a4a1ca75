"""One benchmark trial on a pool of workers, its summary, the real-time criterion and the search."""

from __future__ import annotations

import math
import os
import time
from pathlib import Path

import msgspec
import numpy as np

from companion.bench.cpu_usage import machine_ticks, proc_cpu_s
from companion.bench.swarm_missions import bench_mission
from companion.bench.trial_figures import (
    FailedTrial,
    JudgedTrial,
    Phases,
    Spread,
    TrialFigures,
    TrialRow,
    TrialSummary,
    UavLatency,
    ViewerFigures,
)
from companion.bench.uav_worker import ALIVE_S, UavRun, WorkerReady
from companion.bench.worker_pool import STARTUP_S, Pool, Router, Viewer
from companion.contracts.mission import Mission

LATENCY_TARGET_MS = 5.0
# real-time criterion (see realtime_verdict)
P99_SHARE = 0.5
MISSING_SHARE = 0.01


def _pct(values: np.ndarray | list[float], q: float) -> float:
    """The q-th percentile of `values` (NaN when there are none)."""
    return float(np.percentile(values, q)) if len(values) else math.nan


def trial(
    pool: Pool, mission: Mission, steps: int, period: float, tmp: Path, viewer: bool = False
) -> TrialFigures:
    """One trial on mission.n_uavs workers (lockstep when period == 0): the raw figures.

    With `viewer`, a `Viewer` watches the mesh from before the first step to after the last."""
    n = mission.n_uavs
    path = tmp / f"{mission.mesh.key_prefix}.json"
    path.write_bytes(msgspec.json.encode(mission))
    workers = pool.take(n)
    router = Router(mission.mesh.router) if mission.mesh.mode == "client" else None
    watcher: Viewer | None = None
    seen: ViewerFigures | None = None
    try:
        for i, w in enumerate(workers):
            w.send(op="open", mission=str(path), uav=i, steps=steps, period=period)
        ready = [msgspec.convert(w.recv("ready", ALIVE_S + 120), WorkerReady) for w in workers]
        absent = sum(len(r.missing) for r in ready)
        if viewer:
            watcher = Viewer(path, tmp / f"{mission.mesh.key_prefix}-viewer.log")
            watcher.wait_attached(n, STARTUP_S)
        start = time.time() + 1.0
        b0, t0 = machine_ticks()
        r0 = proc_cpu_s(router.proc.pid) if router else 0.0
        v0 = watcher.cpu_s() if watcher else 0.0
        for w in workers:
            w.send(op="go", start=start)
        budget = steps * (period or 1.0) + 120
        results = [msgspec.convert(w.recv("result", budget), UavRun) for w in workers]
        b1, t1 = machine_ticks()
        r1 = proc_cpu_s(router.proc.pid) if router else 0.0
        v1 = watcher.cpu_s() if watcher else 0.0
        wall = max(r.wall_s for r in results)
        if watcher is not None:
            time.sleep(1.0)  # the last step closes on the viewer
            seen = ViewerFigures(
                **msgspec.structs.asdict(watcher.status()),
                cpu_s=v1 - v0,
                browser=watcher.browser is not None,
                cores=(v1 - v0) / wall,
                cpu_ms_per_step=1e3 * (v1 - v0) / steps,
            )
        for w in workers:
            w.send(op="close")
        for w in workers:
            w.recv("closed", 60)
    finally:
        if watcher is not None:
            watcher.stop()
        if router is not None:
            router.stop()
        path.unlink(missing_ok=True)
    cores = os.cpu_count() or 1
    return TrialFigures(
        n=n,
        mode=mission.mesh.mode,
        steps=steps,
        period=period,
        absent_at_start=absent,
        results=results,
        swarm_cores=sum(r.cpu_s for r in results) / wall,
        router_cores=(r1 - r0) / wall,
        machine_busy_cores=cores * (b1 - b0) / max(1, t1 - t0),
        viewer=seen,
    )


def _spread(values: np.ndarray) -> Spread:
    """The median, 99th percentile and maximum of `values`."""
    return Spread(p50=_pct(values, 50), p99=_pct(values, 99), max=float(values.max()))


def _uav_latency(r: UavRun) -> tuple[UavLatency, np.ndarray]:
    """One UAV's step latency figures, and its step times (ms)."""
    ph = np.array(r.phases_ms).reshape(-1, 4)
    total = ph.sum(axis=1)
    latency = UavLatency(
        uav=r.uav,
        p50=_pct(total, 50),
        p99=_pct(total, 99),
        max=float(total.max()) if len(total) else math.nan,
        median_phases=Phases(*np.median(ph, axis=0).tolist()),
    )
    return latency, total


def summarize(t: TrialFigures) -> TrialSummary:
    """Per-UAV and overall figures of a trial (milliseconds)."""
    figures = [_uav_latency(r) for r in t.results]
    allv = np.concatenate([total for _, total in figures]) if figures else np.zeros(0)
    lag = np.concatenate([np.array(r.lag_ms) for r in t.results])
    n, steps = t.n, t.steps
    stats = [r.stats for r in t.results]
    return TrialSummary(
        n=n,
        mode=t.mode,
        period_s=t.period,
        steps=steps,
        per_uav=[latency for latency, _ in figures],
        latency_ms=_spread(allv),
        lag_ms=_spread(lag),
        overruns=int(np.count_nonzero(lag > 1e3 * t.period)) if t.period > 0 else 0,
        missing=sum(r.missing for r in t.results),
        expected=n * (n - 1) * max(0, steps - 1),
        absent_at_start=t.absent_at_start,
        stale=sum(m.stale for m in stats),
        lost=sum(m.lost for m in stats),
        malformed=sum(m.malformed for m in stats),
        rejected=sum(m.spoofed + m.unauthenticated + m.forged for m in stats),
        received=sum(m.received for m in stats),
        swarm_cores=t.swarm_cores,
        router_cores=t.router_cores,
        machine_busy_cores=t.machine_busy_cores,
        viewer=t.viewer,
    )


def realtime_verdict(s: TrialSummary) -> tuple[bool, str]:
    """The real-time criterion: (pass, why) of a trial's summary.

    With T the step period, "lag" a step's completion time (end of
    inbox -> step -> publish -> MAVLink command) minus its scheduled start k*T, a trial passes iff

    1. every UAV saw all N-1 peers alive before the start and finished every step;
    2. no overrun: lag <= T for every UAV and every step;
    3. p99 of lag over all UAVs and steps <= 0.5 T;
    4. delivery: the peers' step k-1 bundles not yet held when step k starts, and the stale
       bundles (arriving after their step), each <= 1 % of the N(N-1)(steps-1) expected; no
       malformed bundle and no lost message.
    """
    period_ms = 1e3 * s.period_s
    limit = MISSING_SHARE * max(1, s.expected)
    problems = []
    if s.absent_at_start:
        problems.append(f"{s.absent_at_start} peer sightings missing at start")
    if s.overruns:
        problems.append(f"{s.overruns} overruns")
    if s.lag_ms.p99 > P99_SHARE * period_ms:
        problems.append(f"lag p99 {s.lag_ms.p99:.0f} ms > {P99_SHARE * period_ms:.0f} ms")
    if s.missing > limit:
        problems.append(f"{s.missing} late bundles")
    if s.stale > limit:
        problems.append(f"{s.stale} stale bundles")
    if s.malformed or s.lost:
        problems.append(f"{s.malformed} malformed, {s.lost} lost")
    return not problems, "; ".join(problems) or "ok"


def format_latency(s: TrialSummary) -> list[str]:
    """The printed lines of a latency run: every UAV, all of them, and the CPU and bundles."""
    lines = []
    for u in s.per_uav:
        ph = u.median_phases
        lines.append(
            f"  uav {u.uav}: p50 {u.p50:.2f} ms  p99 {u.p99:.2f} ms  max {u.max:.2f} ms"
            f"   (medians: inbox {ph.inbox:.3f}, agent {ph.agent:.2f}, publish {ph.publish:.3f},"
            f" mavlink {ph.mavlink:.3f} ms)"
        )
    a = s.latency_ms
    verdict = "meets" if a.p99 < LATENCY_TARGET_MS else "MISSES"
    lines.append(
        f"  all:   p50 {a.p50:.2f} ms  p99 {a.p99:.2f} ms  max {a.max:.2f} ms"
        f"   ({verdict} the target p99 < {LATENCY_TARGET_MS:g} ms)"
    )
    lines.append(
        f"  cpu: swarm {s.swarm_cores:.2f} cores; machine busy {s.machine_busy_cores:.2f} cores;"
        f" late bundles {s.missing}, stale {s.stale}, lost {s.lost}"
    )
    return lines


def _fmt_trial(s: TrialSummary, verdict: tuple[bool, str]) -> str:
    """The printed line of a search trial and its verdict."""
    lat, lag = s.latency_ms, s.lag_ms
    router = f" + router {s.router_cores:.2f}" if s.mode == "client" else ""
    return (
        f"  N={s.n:>3}: {'PASS' if verdict[0] else 'FAIL'}  step p50/p99/max "
        f"{lat.p50:.1f}/{lat.p99:.1f}/{lat.max:.1f} ms,"
        f" lag p99/max {lag.p99:.0f}/{lag.max:.0f} ms,"
        f" overruns {s.overruns}, late {s.missing}/{s.expected}, stale {s.stale},"
        f" lost {s.lost}; cpu swarm {s.swarm_cores:.2f}{router} cores,"
        f" machine busy {s.machine_busy_cores:.2f} cores" + ("" if verdict[0] else f"  [{verdict[1]}]")
    )


def search(
    pool: Pool, base: Mission, mode: str, sizes: list[int], steps: int, period: float, tmp: Path, tag: str
) -> tuple[int, list[TrialRow]]:
    """Trials over increasing N until one fails; the largest passing N and every trial's row."""
    best = 0
    rows: list[TrialRow] = []
    print(f"real-time swarm, {mode} mode, step period {period:g} s, {steps} steps per trial:", flush=True)
    for n in sizes:
        mission = bench_mission(base, n, mode, f"{tag}{mode[0]}{n}")
        row: TrialRow
        try:
            s = summarize(trial(pool, mission, steps, period, tmp))
        except RuntimeError as exc:
            row = FailedTrial(n=n, mode=mode, period_s=period, error=str(exc), passed=False, why=str(exc))
            print(f"  N={n:>3}: FAIL  [{exc}]", flush=True)
        else:
            verdict = realtime_verdict(s)
            row = JudgedTrial(**msgspec.structs.asdict(s), passed=verdict[0], why=verdict[1])
            print(_fmt_trial(s, verdict), flush=True)
        rows.append(row)
        if not row.passed:
            break
        best = n
    print(f"  largest real-time swarm in {mode} mode at {period:g} s: {best} UAVs", flush=True)
    return best, rows

