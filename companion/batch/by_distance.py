"""Which targets one algorithm finds sooner than another, binned by distance from the start.

The input is an `uavsearch mc` output's targets.csv, paired target by target and binned by the
target's distance from its run's start layout.

Run r of every algorithm has the same targets (common random numbers), listed in the same order,
so each target's first-seen step (an unfound target counting as the run's length) is compared
directly. In each distance bin, a run's mean difference over its targets in the bin is one
observation and the runs are the sample (Student t interval, `stats.mean_ci`). The start layout
is the mission's, or run r's own from starts.csv (`mc --random-starts`).
"""

from __future__ import annotations

import csv
import itertools
import json
from collections import defaultdict
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from companion.batch.stats import Interval, mean_ci
from companion.core.feasibility import load_mission
from companion.core.world import build_grid

DEFAULT_EDGES = (0.0, 400.0, 800.0, 1200.0, 1600.0, 1e9)
COLUMNS = (
    "low_m",
    "high_m",
    "targets",
    "runs",
    "mean_step",
    "baseline_mean_step",
    "difference",
    "difference_low",
    "difference_high",
    "sooner",
    "later",
)


@dataclass(frozen=True)
class DistanceBin:
    """Targets between `low` and `high` metres from their run's start centroid."""

    low: float
    high: float
    targets: int
    mean_step: float  # the algorithm's mean first-seen step over these targets
    baseline_mean_step: float
    difference: Interval  # algorithm - baseline, the runs' means as the sample
    sooner: int  # targets the algorithm saw first
    later: int

    def row(self) -> list[float | int]:
        d = self.difference
        return [
            self.low,
            self.high,
            self.targets,
            d.n,
            self.mean_step,
            self.baseline_mean_step,
            d.estimate,
            d.low,
            d.high,
            self.sooner,
            self.later,
        ]


def _start_centroids(out: Path, runs: Sequence[int]) -> dict[int, tuple[float, float]]:
    """Each run's start centroid: from starts.csv if the study drew them, else the mission's."""
    starts = out / "starts.csv"
    if starts.exists():
        points: dict[int, list[tuple[float, float]]] = defaultdict(list)
        with starts.open() as f:
            for row in csv.DictReader(f):
                points[int(row["run"])].append((float(row["x"]), float(row["y"])))
        means = {r: np.mean(points[r], axis=0) for r in runs}
        return {r: (float(m[0]), float(m[1])) for r, m in means.items()}
    mission = load_mission(out / "mission.toml")
    centre = (
        float(np.mean([v.x for v in mission.vehicles])),
        float(np.mean([v.y for v in mission.vehicles])),
    )
    return {r: centre for r in runs}


def targets_by_distance(
    out: Path, algorithm: str = "proposed", baseline: str = "no-ta", edges: Sequence[float] = DEFAULT_EDGES
) -> list[DistanceBin]:
    """The bins of `edges` (metres, increasing) that hold targets, from `mc`'s output folder `out`."""
    if list(edges) != sorted(edges) or len(edges) < 2:
        raise ValueError(f"bin edges must be at least two increasing distances, got {list(edges)}")
    steps = int(json.loads((out / "summary.json").read_text())["_meta"]["steps"])
    grid = build_grid(load_mission(out / "mission.toml"))
    found: dict[tuple[str, int], list[tuple[int, int]]] = defaultdict(list)
    with (out / "targets.csv").open() as f:
        for row in csv.DictReader(f):
            found[(row["algorithm"], int(row["run"]))].append((int(row["cell"]), int(row["found_step"])))
    runs = sorted(r for a, r in found if a == algorithm)
    if not runs:
        raise ValueError(f"{out / 'targets.csv'}: no runs of {algorithm!r}")
    centroids = _start_centroids(out, runs)
    rows = []  # run, distance, algorithm's step, baseline's step
    for run in runs:
        mine, theirs = found[(algorithm, run)], found.get((baseline, run))
        if theirs is None or [c for c, _ in mine] != [c for c, _ in theirs]:
            raise ValueError(
                f"{out / 'targets.csv'}: run {run} of {baseline!r} is not paired with {algorithm!r}'s"
            )
        cx, cy = centroids[run]
        for (cell, a), (_, b) in zip(mine, theirs, strict=True):
            x, y = grid.centres[cell]
            rows.append(
                (run, float(np.hypot(x - cx, y - cy)), a if a >= 0 else steps, b if b >= 0 else steps)
            )
    table = np.array(rows, dtype=float)
    bins = []
    for low, high in itertools.pairwise(edges):
        sel = table[(table[:, 1] >= low) & (table[:, 1] < high)]
        if len(sel) == 0:
            continue
        per_run = [
            float(np.mean(sel[sel[:, 0] == r, 2] - sel[sel[:, 0] == r, 3])) for r in np.unique(sel[:, 0])
        ]
        diff = sel[:, 2] - sel[:, 3]
        bins.append(
            DistanceBin(
                low,
                high,
                len(sel),
                float(sel[:, 2].mean()),
                float(sel[:, 3].mean()),
                mean_ci(per_run),
                int((diff < 0).sum()),
                int((diff > 0).sum()),
            )
        )
    return bins


def write_csv(path: Path, bins: Sequence[DistanceBin]) -> None:
    with path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(COLUMNS)
        w.writerows(b.row() for b in bins)
