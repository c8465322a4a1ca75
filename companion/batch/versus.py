"""Two `uavsearch mc` outputs of the same runs compared run by run, with paired changes (eq. 30).

The outputs share the mission, seed and run indices (two code versions or two settings). For each
algorithm in both: the paired change in mean target time and in mean uncertainty over the run
(eq. 30), with Student t 95 % intervals, and each output's closest approach and runs with an
event. Run r is the same mission instance in both (common random numbers), so the paired
differences isolate what changed.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from companion.batch.stats import Interval, mean_ci

METRICS = ("mean_target_time", "mean_uncertainty")


@dataclass(frozen=True)
class Change:
    """One algorithm's figures in the `before` and `after` outputs over their common runs."""

    algorithm: str
    runs: int
    before: dict[str, float]  # each metric's mean
    after: dict[str, float]
    change: dict[str, Interval]  # after - before, paired
    closest: tuple[float, float]  # the smallest closest approach of each output (m)
    events: tuple[int, int]  # runs with a separation or link event in each


def _runs(folder: Path) -> dict[tuple[str, int], dict[str, str]]:
    path = folder / "runs.csv"
    if not path.is_file():
        raise ValueError(f"{folder}: no runs.csv (the output folder of `uavsearch mc`)")
    with path.open(newline="") as f:
        return {(r["algorithm"], int(r["run"])): r for r in csv.DictReader(f)}


def _event(row: dict[str, str]) -> bool:
    return int(row["separation_losses"]) > 0 or int(row["link_losses"]) > 0


def compare(before: Path, after: Path) -> list[Change]:
    """The paired changes from `before` to `after`, per algorithm present in both.

    Raises ValueError when they share no run or disagree on a run's seed or length.
    """
    a, b = _runs(before), _runs(after)
    out = []
    for algorithm in dict.fromkeys(k[0] for k in a):
        keys = sorted(k for k in a if k[0] == algorithm and k in b)
        if not keys:
            continue
        for k in keys:
            if (a[k]["seed"], a[k]["steps"]) != (b[k]["seed"], b[k]["steps"]):
                raise ValueError(
                    f"{algorithm} run {k[1]}: not the same run in {before} and {after} (seed, steps)"
                )
        x = {m: np.array([float(a[k][m]) for k in keys]) for m in METRICS}
        y = {m: np.array([float(b[k][m]) for k in keys]) for m in METRICS}
        out.append(
            Change(
                algorithm,
                len(keys),
                {m: float(x[m].mean()) for m in METRICS},
                {m: float(y[m].mean()) for m in METRICS},
                {m: mean_ci(y[m] - x[m]) for m in METRICS},
                (
                    min(float(a[k]["closest_approach"]) for k in keys),
                    min(float(b[k]["closest_approach"]) for k in keys),
                ),
                (sum(_event(a[k]) for k in keys), sum(_event(b[k]) for k in keys)),
            )
        )
    if not out:
        raise ValueError(f"{before} and {after} share no run of any algorithm")
    return out
