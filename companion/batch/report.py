"""Files a Monte Carlo study writes: summary.json, runs.csv, curves.csv, trajectories.csv."""

from __future__ import annotations

import csv
import json
import math
import os
import shutil
import tomllib
from collections.abc import Mapping, Sequence
from pathlib import Path

import msgspec
import numpy as np

from companion.batch.confirmation import confirm_time, never_confirmed, run_pos
from companion.batch.engine import RunResult
from companion.batch.montecarlo import Summary, summarize
from companion.contracts.mission import Mission

TRAJECTORY_COLUMNS = ("algorithm", "run", "step", "uav", "x", "y", "heading", "task")
STEP_COLUMNS = ("algorithm", "run", "step", "uncertainty", "found", "coverage", "lambda2", "min_distance")
TARGET_COLUMNS = ("algorithm", "run", "cell", "found_step")
START_COLUMNS = ("run", "layout", "uav", "x", "y", "heading_deg")


class StudySummary(msgspec.Struct, frozen=True):
    """summary.json: one `montecarlo.Summary` per algorithm and the study's metadata (its "_meta")."""

    algorithms: dict[str, Summary]
    meta: msgspec.Struct | None = None

    def to_json(self) -> dict[str, object]:
        """summary.json's content: the algorithms' summaries by name, then "_meta"."""
        content: dict[str, object] = {name: msgspec.to_builtins(s) for name, s in self.algorithms.items()}
        if self.meta is not None:
            content["_meta"] = msgspec.to_builtins(self.meta)
        return content


def write_summary(
    out: Path, results: Mapping[str, Sequence[RunResult]], meta: msgspec.Struct | None = None
) -> StudySummary:
    """Write summary.json: one `montecarlo.Summary` per algorithm, plus optional "_meta".

    Returns it (what the command line prints from)."""
    summary = StudySummary({name: summarize(list(runs)) for name, runs in results.items()}, meta)
    (out / "summary.json").write_text(json.dumps(summary.to_json(), indent=2) + "\n")
    return summary


def refused_share(r: RunResult) -> float:
    """The share of the RHC's first choices that the safety layer refused in run `r` (NaN: none)."""
    asked = r.extras.get("first_choices", 0)
    return r.extras.get("first_choices_refused", 0) / asked if asked else math.nan


def write_runs(out: Path, results: Mapping[str, Sequence[RunResult]]) -> None:
    """runs.csv: one row of metrics per run.

    Columns: mean_uncertainty: eq. 30 averaged over the run;
    closest_approach: of any pair that can meet between sampling moments (`RunResult.approach`);
    separation_losses, link_losses: steps with such a pair within R_s, sampling moments with
    lambda_2 = 0; keepout_entries: chords between sampling points that entered a no-fly zone
    inflated by the margin (`search_area.keepout_pieces`; empty for a convex region without zones);
    first_choice_refused: the share of the RHC's first choices the safety layer refused;
    mean_confirm_time, never_confirmed, false_confirmations: the confirmations (`confirmation`;
    for a perfect sensor the first look confirms: mean_target_time, targets - targets_found, 0)."""
    with (out / "runs.csv").open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(
            [
                "algorithm",
                "run",
                "seed",
                "steps",
                "mean_target_time",
                "targets_found",
                "targets",
                "final_uncertainty",
                "mean_uncertainty",
                "final_coverage",
                "min_lambda2",
                "min_distance",
                "closest_approach",
                "separation_losses",
                "link_losses",
                "keepout_entries",
                "first_choice_refused",
                "seconds",
                "mean_confirm_time",
                "never_confirmed",
                "false_confirmations",
            ]
        )
        for name, runs in results.items():
            for r in runs:
                tt = float(r.target_times().mean()) if len(r.target_steps) else 0.0
                w.writerow(
                    [
                        name,
                        r.run,
                        r.seed,
                        r.steps,
                        f"{tt:.3f}",
                        int(np.sum(r.target_steps >= 0)),
                        len(r.target_steps),
                        f"{r.uncertainty[-1]:.6f}",
                        f"{r.uncertainty.mean():.6f}",
                        f"{r.coverage[-1]:.6f}",
                        f"{r.lambda2.min():.6f}",
                        f"{r.min_distance.min():.3f}",
                        f"{r.approach.min():.3f}",
                        r.separation_losses,
                        r.link_losses,
                        "" if r.keepout_entries is None else r.keepout_entries,
                        f"{refused_share(r):.4f}",
                        f"{r.seconds:.4f}",
                        f"{confirm_time(r):.3f}",
                        never_confirmed(r),
                        r.false_confirmations,
                    ]
                )


def mean_band(curves: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean over runs (rows) and the half-width of its 95 % confidence interval, per step."""
    mean = curves.mean(axis=0)
    if curves.shape[0] < 2:
        return mean, np.zeros_like(mean)
    return mean, 1.96 * curves.std(axis=0, ddof=1) / math.sqrt(curves.shape[0])


def write_curves(out: Path, results: Mapping[str, Sequence[RunResult]]) -> None:
    """curves.csv: per algorithm and step, the mean curves with their 95 % CI.

    The mean and 95 % CI of uncertainty (eq. 30), targets found and coverage, the minimum over
    runs of lambda_2 and of the inter-UAV distance, and the probability of success (POS: the
    fraction of targets confirmed by the step, `confirmation.pos_curve`) with its 95 % CI."""
    with (out / "curves.csv").open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(
            [
                "algorithm",
                "step",
                "uncertainty",
                "uncertainty_ci95",
                "found",
                "found_ci95",
                "coverage",
                "coverage_ci95",
                "min_lambda2",
                "min_distance",
                "pos",
                "pos_ci95",
            ]
        )
        for name, runs in results.items():
            unc, unc_ci = mean_band(np.array([r.uncertainty for r in runs]))
            found, found_ci = mean_band(np.array([r.found for r in runs]))
            cov, cov_ci = mean_band(np.array([r.coverage for r in runs]))
            lam = np.min([r.lambda2 for r in runs], axis=0)
            dist = np.min([r.min_distance for r in runs], axis=0)
            pos, pos_ci = mean_band(np.array([run_pos(r) for r in runs]))
            for k in range(len(unc)):
                w.writerow(
                    [
                        name,
                        k,
                        f"{unc[k]:.6f}",
                        f"{unc_ci[k]:.6f}",
                        f"{found[k]:.4f}",
                        f"{found_ci[k]:.4f}",
                        f"{cov[k]:.6f}",
                        f"{cov_ci[k]:.6f}",
                        f"{lam[k]:.6f}",
                        f"{dist[k]:.3f}",
                        f"{pos[k]:.4f}",
                        f"{pos_ci[k]:.4f}",
                    ]
                )


def write_trajectories(out: Path, results: Mapping[str, Sequence[RunResult]]) -> int:
    """trajectories.csv for every recorded run; returns the number of runs written."""
    written = 0
    with (out / "trajectories.csv").open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(TRAJECTORY_COLUMNS)
        for name, runs in results.items():
            for r in runs:
                if r.trajectory is None or r.tasks is None:
                    continue
                written += 1
                for k in range(r.steps):
                    for i in range(r.trajectory.shape[1]):
                        x, y, h = r.trajectory[k, i]
                        w.writerow(
                            [name, r.run, k, i, f"{x:.3f}", f"{y:.3f}", f"{h:.6f}", int(r.tasks[k, i])]
                        )
    return written


def _recorded(results: Mapping[str, Sequence[RunResult]]) -> list[RunResult]:
    return [r for runs in results.values() for r in runs if r.trajectory is not None]


def write_steps(out: Path, results: Mapping[str, Sequence[RunResult]]) -> None:
    """steps.csv for every recorded run: the metrics at each step.

    Eq. 30, targets found, coverage, lambda_2 and the minimum distance at each step (what
    `uavsearch view --replay` plots)."""
    with (out / "steps.csv").open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(STEP_COLUMNS)
        for r in _recorded(results):
            for k in range(r.steps):
                w.writerow(
                    [
                        r.algorithm,
                        r.run,
                        k,
                        f"{r.uncertainty[k]:.7f}",
                        int(r.found[k]),
                        f"{r.coverage[k]:.6f}",
                        f"{r.lambda2[k]:.6f}",
                        f"{r.min_distance[k]:.3f}",
                    ]
                )


def write_targets(out: Path, results: Mapping[str, Sequence[RunResult]]) -> None:
    """targets.csv for every run: each ground-truth target's cell and the step it was first seen.

    A step of -1: never. Per-target questions (which targets one algorithm finds sooner) are
    answered from it paired, run by run."""
    with (out / "targets.csv").open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(TARGET_COLUMNS)
        for r in (r for runs in results.values() for r in runs):
            for cell, step in zip(r.target_cells.tolist(), r.target_steps.tolist(), strict=True):
                w.writerow([r.algorithm, r.run, cell, step])


def write_starts(out: Path, drawn: Sequence[tuple[Mission, str]]) -> None:
    """starts.csv: the start layout of each run, the same for every algorithm.

    Written by `uavsearch mc --random-starts`."""
    with (out / "starts.csv").open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(START_COLUMNS)
        for run, (mission, layout) in enumerate(drawn):
            for i, v in enumerate(mission.vehicles):
                w.writerow([run, layout, i, v.x, v.y, v.heading_deg])


def copy_mission(mission: Path, out: Path) -> None:
    """out/mission.toml: the mission file the output came from (`uavsearch view --replay` reads it).

    Its area file (`region.area`), when named relative to the mission and inside its directory,
    is copied to the same place under `out`, so that the copy reads as the original does."""
    target = out / "mission.toml"
    if not (target.exists() and target.samefile(mission)):
        shutil.copyfile(mission, target)
    region = tomllib.loads(mission.read_text()).get("region", {})
    area = region.get("area", "") if isinstance(region, dict) else ""
    rel = Path(os.path.normpath(area)) if isinstance(area, str) and area else None
    if rel is None or rel.is_absolute() or rel.parts[0] == "..":
        return
    copy = out / rel
    if not (copy.exists() and copy.samefile(mission.parent / rel)):
        copy.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(mission.parent / rel, copy)
