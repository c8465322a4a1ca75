"""The figures of the companion benchmark's trials: raw, summarized, judged and searched.

`trials.trial` returns a `TrialFigures`, `trials.summarize` a `TrialSummary` (milliseconds),
`trials.search` one `TrialRow` per trial; encoded with `msgspec.to_builtins` they are the
`--json` report's documents (docs/performance.md, "Companion").
"""

from __future__ import annotations

from typing import Literal

import msgspec

from companion.bench.uav_worker import UavRun
from companion.bench.worker_pool import ViewerStatus

MeshMode = Literal["peer", "client"]


class ViewerFigures(ViewerStatus, frozen=True):
    """What a viewer on a trial saw (its /api/status after the last step) and what it cost.

    `cpu_s` is the view server's and browser's CPU time over the trial, `cores` that over the
    trial's wall time; `browser` whether a headless Chromium was on the page."""

    cpu_s: float
    browser: bool
    cores: float
    cpu_ms_per_step: float


class TrialFigures(msgspec.Struct, frozen=True):
    """The raw figures of one trial: every worker's run and the CPU shares, in cores."""

    n: int
    mode: MeshMode
    steps: int
    period: float
    absent_at_start: int
    results: list[UavRun]
    swarm_cores: float
    router_cores: float
    machine_busy_cores: float
    viewer: ViewerFigures | None


class Spread(msgspec.Struct, frozen=True):
    """The median, 99th percentile and maximum of a set of times (ms; NaN when empty)."""

    p50: float
    p99: float
    max: float


class Phases(msgspec.Struct, frozen=True):
    """The milliseconds of a step's phases: Mesh.inbox, Agent.step, Mesh.publish, MAVLink packing."""

    inbox: float
    agent: float
    publish: float
    mavlink: float


class UavLatency(msgspec.Struct, frozen=True):
    """One UAV's step latency over a trial (ms) and the median of each phase."""

    uav: int
    p50: float
    p99: float
    max: float
    median_phases: Phases


class TrialSummary(msgspec.Struct, frozen=True):
    """The per-UAV and overall figures of a trial (milliseconds; bundle counts; cores).

    `latency_ms` is the step latency (observation in to command out), `lag_ms` a step's completion
    behind its scheduled start; `missing` the peers' bundles not yet held at a step's start out of
    `expected`; `stale`, `lost`, `malformed`, `rejected` and `received` the mesh's counters."""

    n: int
    mode: MeshMode
    period_s: float
    steps: int
    per_uav: list[UavLatency]
    latency_ms: Spread
    lag_ms: Spread
    overruns: int
    missing: int
    expected: int
    absent_at_start: int
    stale: int
    lost: int
    malformed: int
    rejected: int
    received: int
    swarm_cores: float
    router_cores: float
    machine_busy_cores: float
    viewer: ViewerFigures | None


class JudgedTrial(TrialSummary, frozen=True):
    """A search trial's summary with its real-time verdict (`trials.realtime_verdict`)."""

    passed: bool = msgspec.field(name="pass")
    why: str


class FailedTrial(msgspec.Struct, frozen=True):
    """A search trial that did not run to its end: the error, which is also why it fails."""

    n: int
    mode: str
    period_s: float
    error: str
    passed: bool = msgspec.field(name="pass")
    why: str


TrialRow = JudgedTrial | FailedTrial


class SwarmSearch(msgspec.Struct, frozen=True):
    """The real-time search of one mode at one period: the largest passing N and every trial."""

    largest: int
    trials: list[TrialRow]
