"""`uavsearch evaluate`: the proposed method against each baseline on a held-out set of missions.

Every algorithm flies R runs of every mission, run r being the same instance for all three
(`paired`). For each mission, baseline and metric (`paired.METRICS`, both lower-is-better) the
paired differences proposed - baseline over the R runs give the mission's mean difference and its
Student t 95 % interval; the proposed method *wins* the mission when that mean is below 0. Overall,
the missions are the sample: the mean of the per-mission mean differences with its t interval over
the N missions (and the same for the differences relative to the baseline's mission mean), and the
win rate with its Wilson interval. `by_density` splits the missions at the median area per UAV
(the held-out study's finding: the proposed method's lead is on thin swarms; docs/results.md).
"""

from __future__ import annotations

import csv
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import msgspec
import numpy as np

from companion.batch import plots
from companion.batch.executors import RunExecutor
from companion.batch.paired import CONFIRMATIONS, METRICS, measure, specs_grid, write_json
from companion.batch.stats import Interval, mean_ci, wilson
from companion.contracts.mission import ALGORITHMS, Mission

PROPOSED = "proposed"
MIN_RUNS = 2  # a per-mission interval needs two paired runs
RUN_COLUMNS = ("mission", "algorithm", "run", *METRICS, *CONFIRMATIONS)


class MissionRow(msgspec.Struct, frozen=True):
    """One mission, baseline and metric: the means and their paired difference.

    One mission, baseline and metric: the first algorithm's mean (`proposed`), the baseline's,
    and the paired difference first - baseline over the runs with its Student t interval."""

    mission: str
    baseline: str
    metric: str
    runs: int
    proposed: float
    baseline_value: float
    difference: float
    difference_low: float
    difference_high: float


class OverallRow(msgspec.Struct, frozen=True):
    """One baseline and metric over the missions.

    One baseline and metric over the missions: the mean of the per-mission differences (absolute
    and relative to the baseline) with t intervals, the wins, ties and losses with the Wilson
    interval of the win rate, and the missions whose own interval excludes 0."""

    baseline: str
    metric: str
    missions: int
    runs: int
    difference: float
    difference_low: float
    difference_high: float
    relative_difference: float
    relative_difference_low: float
    relative_difference_high: float
    wins: int
    ties: int
    losses: int
    win_rate: float
    win_rate_low: float
    win_rate_high: float
    significantly_better: int
    significantly_worse: int


class PairedTable(msgspec.Struct, frozen=True):
    """`paired_table`: one row per (mission, baseline, metric) and per (baseline, metric)."""

    missions: list[MissionRow]
    overall: list[OverallRow]


class DensityRow(msgspec.Struct, frozen=True):
    """One baseline and metric on the dense or thin half of the missions (`by_density`)."""

    baseline: str
    metric: str
    half: str
    km2_per_uav: str
    missions: int
    difference: float
    difference_low: float
    difference_high: float
    wins: int
    win_rate: float
    win_rate_low: float
    win_rate_high: float


class MissionFeatures(msgspec.Struct, frozen=True):
    """What describes a mission in the evaluation's tables (`mission_features`)."""

    mission: str
    uavs: int
    mode: str
    seed: int
    area_km2: float
    km2_per_uav: float
    centres: int
    targets: int


class EvaluationMeta(msgspec.Struct, frozen=True):
    """evaluate.json's "meta": the study's size and how its figures read."""

    missions: int
    runs: int
    steps: int
    algorithms: list[str]
    start_layouts: list[str] | str  # the layouts drawn from, or "each mission's"
    metrics: dict[str, str] = msgspec.field(
        default_factory=lambda: {
            "target_time": "mean over targets of the step each was first seen (unfound: steps)",
            "mean_uncertainty": "eq. 30 averaged over the run's steps",
        }
    )
    difference: str = "proposed - baseline (negative: the proposed method is better)"
    win: str = "the proposed method's mean over the mission's runs is below the baseline's"


class Evaluation(msgspec.Struct, frozen=True):
    """What evaluate.json holds.

    The meta (and how the missions were made: `origin`), the missions' features, and the
    per-mission, overall and by-density tables."""

    meta: EvaluationMeta
    origin: dict[str, object]  # the caller's: generated (count, seed, family) or a folder, weights
    mission_info: list[MissionFeatures]
    missions: list[MissionRow]
    overall: list[OverallRow]
    by_density: list[DensityRow]

    def to_json(self) -> dict[str, object]:
        """evaluate.json's content: `origin` goes into "meta", after its own fields."""
        return {
            "meta": msgspec.to_builtins(self.meta) | self.origin,
            "mission_info": msgspec.to_builtins(self.mission_info),
            "missions": msgspec.to_builtins(self.missions),
            "overall": msgspec.to_builtins(self.overall),
            "by_density": msgspec.to_builtins(self.by_density),
        }


def _overall(
    baseline: str, metric: str, runs: int, base: np.ndarray, per_mission: list[Interval]
) -> OverallRow:
    """The per-mission differences of one baseline and metric, over the missions."""
    n = len(per_mission)
    means = np.array([ci.estimate for ci in per_mission])
    relative = means / np.where(base > 0, base, np.nan)
    wins, ties = int(np.sum(means < 0)), int(np.sum(means == 0))
    d, r, w = mean_ci(means), mean_ci(relative[np.isfinite(relative)]), wilson(wins, n)
    return OverallRow(
        baseline, metric, n, runs, d.estimate, d.low, d.high, r.estimate, r.low, r.high,
        wins, ties, n - wins - ties, w.estimate, w.low, w.high,
        sum(ci.high < 0 for ci in per_mission), sum(ci.low > 0 for ci in per_mission),
    )  # fmt: skip


def paired_table(values: np.ndarray, algorithms: Sequence[str], names: Sequence[str]) -> PairedTable:
    """Per-mission and overall paired comparisons of `algorithms[0]` against each other algorithm.

    `values[m, a, r, q]` is metric q of run r of algorithm a on mission m (`names[m]`)."""
    n_missions, n_algorithms, runs, n_metrics = values.shape
    if n_algorithms < 2 or len(names) != n_missions or n_metrics != len(METRICS):
        raise ValueError("need values[mission, algorithm, run, metric] with two or more algorithms")
    rows, overall = [], []
    for b in range(1, n_algorithms):
        for q, metric in enumerate(METRICS):
            diffs = values[:, 0, :, q] - values[:, b, :, q]  # (missions, runs)
            base = values[:, b, :, q].mean(axis=1)
            per_mission = [mean_ci(d) for d in diffs]
            for m, ci in enumerate(per_mission):
                first = float(values[m, 0, :, q].mean())
                rows.append(
                    MissionRow(
                        names[m],
                        algorithms[b],
                        metric,
                        runs,
                        first,
                        float(base[m]),
                        ci.estimate,
                        ci.low,
                        ci.high,
                    )
                )
            overall.append(_overall(algorithms[b], metric, runs, base, per_mission))
    return PairedTable(rows, overall)


def mission_features(mission: Mission) -> MissionFeatures:
    """What describes a mission in the evaluation's tables.

    What describes a mission in the evaluation's tables: swarm size, kinematics, region area,
    area per UAV (the swarm's density), prior centres and targets."""
    x, y = np.asarray(mission.region.polygon, dtype=float).T
    area = 0.5 * abs(float(np.dot(x, np.roll(y, 1)) - np.dot(y, np.roll(x, 1)))) / 1e6
    return MissionFeatures(
        mission.name,
        mission.n_uavs,
        mission.kinematics.mode,
        mission.seed,
        area,
        area / mission.n_uavs,
        len(mission.prior.centres or ()),
        mission.prior.targets,
    )


def by_density(missions: Sequence[MissionRow], info: Sequence[MissionFeatures]) -> list[DensityRow]:
    """The per-mission rows of `paired_table` split at the median area per UAV.

    Per baseline and metric, the per-mission rows of `paired_table` split at the median area per
    UAV (`mission_features`): for the dense half (at most the median) and the thin half, the mean
    difference with its t interval over the missions and the win rate with its Wilson interval."""
    per_uav = {i.mission: i.km2_per_uav for i in info}
    median = float(np.median(list(per_uav.values())))
    out = []
    for baseline, metric in dict.fromkeys((r.baseline, r.metric) for r in missions):
        rows = [r for r in missions if (r.baseline, r.metric) == (baseline, metric)]
        for half, thin in (("dense", False), ("thin", True)):
            d = np.array([r.difference for r in rows if (per_uav[r.mission] > median) == thin])
            if d.size == 0:
                continue
            wins = int(np.sum(d < 0))
            ci, rate = mean_ci(d), wilson(wins, int(d.size))
            out.append(
                DensityRow(
                    baseline,
                    metric,
                    half,
                    f"{'>' if thin else '<='} {median:.3g}",
                    int(d.size),
                    ci.estimate,
                    ci.low,
                    ci.high,
                    wins,
                    rate.estimate,
                    rate.low,
                    rate.high,
                )
            )
    return out


def evaluate(
    missions: Sequence[Mission],
    runs: int,
    steps: int,
    out: Path,
    executor: RunExecutor | None = None,
    layouts: tuple[str, ...] = (),
    meta: Mapping[str, object] | None = None,
    advance: Callable[[], object] | None = None,
) -> Evaluation:
    """Run the three algorithms on the missions and write the evaluation's files.

    Run the three algorithms on the missions (on `executor`, default a local pool) and write
    evaluate.json, missions.csv, overall.csv, runs.csv (per run: `paired.METRICS` and
    `paired.CONFIRMATIONS`), evaluate.png and evaluate_density.png into `out`; returns what
    evaluate.json holds (what the command line prints)."""
    if runs < MIN_RUNS:
        raise ValueError(f"--runs must be at least {MIN_RUNS} (a per-mission interval needs two paired runs)")
    algorithms = (PROPOSED, *(a for a in ALGORITHMS if a != PROPOSED))
    specs = specs_grid(missions, algorithms, runs, steps, layouts)
    shape = (len(missions), len(algorithms), runs, len(METRICS) + len(CONFIRMATIONS))
    measured = measure(specs, executor, advance, confirmations=True).reshape(shape)
    values = measured[..., : len(METRICS)]
    names = [m.name for m in missions]
    table = paired_table(values, algorithms, names)
    info = [mission_features(m) for m in missions]
    header = EvaluationMeta(len(missions), runs, steps, list(algorithms), list(layouts) or "each mission's")
    result = Evaluation(
        header, dict(meta or {}), info, table.missions, table.overall, by_density(table.missions, info)
    )
    out.mkdir(parents=True, exist_ok=True)
    write_json(out / "evaluate.json", result.to_json())
    _write_csv(out / "missions.csv", table.missions)
    _write_csv(out / "overall.csv", table.overall)
    with (out / "runs.csv").open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(RUN_COLUMNS)
        for m, name in enumerate(names):
            for a, algorithm in enumerate(algorithms):
                for r in range(runs):
                    w.writerow([name, algorithm, r, *(f"{v:.10g}" for v in measured[m, a, r])])
    plots.plot_paired(out / "evaluate.png", table, METRICS)
    plots.plot_density(out / "evaluate_density.png", table, info, METRICS)
    return result


def _write_csv(path: Path, rows: Sequence[msgspec.Struct]) -> None:
    with path.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0].__struct_fields__))
        w.writeheader()
        w.writerows(msgspec.to_builtins(rows))
