"""`uavsearch tune`: the weights the paper does not give, chosen by optimisation on training missions.

A candidate is a set of `[algorithm]` values (`SPACE` or a `--space` file). Every candidate flies
the same R runs of the same N missions (common random numbers) and is scored by `OBJECTIVE`, its
paired relative difference from the current weights (trial 0) over the missions; Optuna's TPE
sampler, seeded, proposes candidates, and the best few are flown again on fresh runs before one is
chosen (`tune`). The budget counts runs, trial 0 and the confirmation included. The reasoning
behind J: docs/results.md, "How the weights were chosen".
"""

from __future__ import annotations

import csv
import tomllib
import warnings
from collections.abc import Callable, Mapping, Sequence
from contextlib import nullcontext
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import msgspec
import numpy as np
import optuna

from companion.batch import plots
from companion.batch.executors import RunExecutor, open_executor
from companion.batch.paired import METRICS, apply_weights, measure, specs_grid, write_json
from companion.batch.stats import Interval, mean_ci
from companion.contracts.mission import ALGORITHMS, Mission, MissionError

SIGNIFICANT = 4  # candidates are rounded to this many significant digits before they are flown
OBJECTIVE = (
    "J = mean over missions m of [(T_m - T0_m) / max(T0_m, 1) + lambda (U_m - U0_m) / U0_m]: T_m, U_m the "
    "mean target time and mean uncertainty over the run (eq. 30) of the candidate's runs of mission m, "
    "T0_m, U0_m those of trial 0 (the weights before) on the same runs; lower is better"
)


@dataclass(frozen=True)
class Weight:
    """A tunable field of `[algorithm]`, its range, and the algorithms whose runs read it.

    The field is named like "kappa", "beta.1" (an element of a pair) or "pheromone.weight" (a field
    of a nested table).
    """

    field: str
    low: float
    high: float
    log: bool = False
    read_by: tuple[str, ...] = ("proposed",)


# The weights the paper does not give. Only ratios matter for beta (eq. 15's reward is income / cost,
# so scaling C_ij changes no choice: beta_1 = 1 fixes the scale, with c_max the threshold on it), for
# chi and delta (eq. 22 takes the best path, so chi_1 = delta_1 = 1 fix the scale of J), and for the
# pheromone's deposit and weight (the field is linear in the deposit): the fixed ones are not tuned.
SPACE: tuple[Weight, ...] = (
    Weight("kappa", 0.3, 30.0, log=True),  # eq. 16: search time of a task per unit area
    Weight("v_max", 0.5, 0.99),  # eq. 21: leave a task once this share of it is seen
    Weight("c_max", 5.0, 2000.0, log=True),  # eq. 21: leave a task that costs more than this
    Weight("beta.1", 0.05, 20.0, log=True),  # eq. 18: communication cost / time cost
    Weight("comm_cost_cap", 0.5, 10.0, log=True),  # eq. 17: saturation exponent per neighbour
    Weight("delta.1", 0.05, 20.0, log=True),  # eq. 25: pull towards the task region (tasks only)
    Weight("chi.1", 0.05, 20.0, log=True, read_by=ALGORITHMS),  # eq. 22: weight of eq. 29's barriers
    Weight("pheromone.weight", 0.05, 20.0, log=True, read_by=("pheromone",)),  # attraction
    Weight("pheromone.evaporation", 0.01, 0.5, read_by=("pheromone",)),
    Weight("pheromone.diffusion", 0.0, 0.5, read_by=("pheromone",)),
)


def load_space(path: str | Path) -> tuple[Weight, ...]:
    """A search space from a TOML file, one table per field.

    For example `[kappa]` with `low`, `high`, optional `log` (false) and `read_by` (["proposed"]).
    """
    p = Path(path)
    try:
        raw = tomllib.loads(p.read_text(encoding="utf-8"))
    except OSError as exc:
        raise MissionError(str(p), "(file)", exc.strerror or str(exc)) from None
    except tomllib.TOMLDecodeError as exc:
        raise MissionError(str(p), "(syntax)", str(exc)) from None
    space = []
    keys = {"low", "high", "log", "read_by"}
    for name, row in raw.items():
        if not isinstance(row, dict):
            raise MissionError(str(p), name, "must be a table with low and high")
        if set(row) - keys:
            raise MissionError(str(p), name, f"unknown keys {sorted(set(row) - keys)}; known: {sorted(keys)}")
        try:
            space.append(msgspec.convert({"field": name, **row}, Weight))
        except msgspec.ValidationError as exc:
            raise MissionError(str(p), name, str(exc)) from None
    return tuple(space)


def _path(field: str) -> list[str | int]:
    return [int(part) if part.isdigit() else part for part in field.split(".")]


def current_value(mission: Mission, field: str) -> object:
    """The value of an `[algorithm]` field ("beta.1", "pheromone.weight") in a mission."""
    node: object = msgspec.to_builtins(mission.algorithm)
    for key in _path(field):
        try:
            node = node[key]  # type: ignore[index]
        except (KeyError, IndexError, TypeError):
            raise ValueError(f"{field!r} is not a field of [algorithm]") from None
    return node


def weights_table(mission: Mission, values: Mapping[str, float]) -> dict[str, Any]:
    """The `[algorithm]` entries that `values` (by field) change, whole.

    A pair or a nested table keeps its other members at the mission's values.
    """
    algorithm = msgspec.json.decode(msgspec.json.encode(mission.algorithm))  # lists and dicts, a copy
    table: dict[str, Any] = {}
    for field, value in values.items():
        top, *rest = _path(field)
        assert isinstance(top, str)
        table.setdefault(top, algorithm[top])
        node = table[top]
        for key in rest[:-1]:
            node = node[key]
        if rest:
            node[rest[-1]] = value
        else:
            table[top] = value
    return table


def check_space(space: Sequence[Weight], missions: Sequence[Mission]) -> None:
    """Raise ValueError unless the search space fits the missions.

    Every row names a numeric field of [algorithm], has low < high (low > 0 on a log scale), and
    holds the missions' current value (trial 0), which they share.
    """
    for w in space:
        value = current_value(missions[0], w.field)
        if not isinstance(value, int | float) or isinstance(value, bool):
            raise ValueError(f"{w.field!r} is not a number in [algorithm]")
        if not w.low < w.high or (w.log and w.low <= 0):
            raise ValueError(
                f"{w.field}: need low < high (and low > 0 on a log scale), got {w.low}, {w.high}"
            )
        if not w.low <= value <= w.high:
            raise ValueError(f"{w.field}: the current value {value} is outside the range [{w.low}, {w.high}]")
        unknown = set(w.read_by) - set(ALGORITHMS)
        if unknown:
            raise ValueError(f"{w.field}: read_by names unknown algorithms {sorted(unknown)}")
        other = next((m for m in missions if current_value(m, w.field) != value), None)
        if other is not None:
            raise ValueError(
                f"{w.field}: the missions disagree ({missions[0].name}: {value}, {other.name}: "
                f"{current_value(other, w.field)}); give them one value with --weights"
            )


def select(space: Sequence[Weight], algorithm: str, params: Sequence[str] | None) -> tuple[Weight, ...]:
    """The rows to tune: those named in `params`, else every row that `algorithm` reads."""
    if params is None:
        chosen = tuple(w for w in space if algorithm in w.read_by)
    else:
        rows = {w.field: w for w in space}
        missing = [p for p in params if p not in rows]
        if missing:
            raise ValueError(f"no search-space row for {', '.join(missing)}; rows: {', '.join(rows)}")
        chosen = tuple(rows[p] for p in params)
        unread = [w.field for w in chosen if algorithm not in w.read_by]
        if unread:
            raise ValueError(f"{algorithm} does not read {', '.join(unread)}: tuning them cannot change it")
    if not chosen:
        raise ValueError(f"nothing to tune for {algorithm}")
    return chosen


@dataclass(frozen=True)
class Score:
    """A candidate against trial 0 on the same runs: the objective J, its parts and its wins.

    The parts are relative differences per mission (mean and t interval over missions); the wins
    are the missions it finds targets sooner on.
    """

    objective: float
    target_time: Interval
    uncertainty: Interval
    wins: int


def score(candidate: np.ndarray, reference: np.ndarray, uncertainty_weight: float) -> Score:
    """`candidate[m, r, q]`, `reference[m, r, q]`: metric q (`paired.METRICS`) of run r of mission m."""
    c, ref = candidate.mean(axis=1), reference.mean(axis=1)  # (missions, metrics)
    time = (c[:, 0] - ref[:, 0]) / np.maximum(ref[:, 0], 1.0)
    unc = (c[:, 1] - ref[:, 1]) / ref[:, 1]
    objective = float(np.mean(time + uncertainty_weight * unc))
    return Score(objective, mean_ci(time), mean_ci(unc), int(np.sum(time < 0)))


def _rounded(value: float) -> float:
    return value if isinstance(value, int) else float(f"{value:.{SIGNIFICANT}g}")


def _distribution(w: Weight, current: object) -> optuna.distributions.BaseDistribution:
    """Integers (n_g, horizon, ...) on an integer range, everything else on a float range."""
    if isinstance(current, int):
        return optuna.distributions.IntDistribution(int(w.low), int(w.high), log=w.log)
    return optuna.distributions.FloatDistribution(w.low, w.high, log=w.log)


def toml_snippet(table: Mapping[str, object]) -> str:
    """`key = value` lines (pairs as arrays, nested tables inline), to paste into [algorithm]."""

    def value(v: object) -> str:
        if isinstance(v, Mapping):
            return "{ " + ", ".join(f"{k} = {value(x)}" for k, x in v.items()) + " }"
        if isinstance(v, list | tuple):
            return "[" + ", ".join(value(x) for x in v) + "]"
        return repr(v) if isinstance(v, float) else str(v)

    return "".join(f"{k} = {value(v)}\n" for k, v in table.items())


@dataclass(frozen=True)
class Setup:
    """What a study flies: the algorithm, its runs and steps, the budget and the confirmation.

    That is the algorithm, R runs of K steps per mission and candidate, a budget in runs, the
    sampler's seed, lambda, the start layouts (empty: each mission's own), and how many of the best
    candidates are flown again on fresh runs before one is chosen.
    """

    algorithm: str
    runs: int
    steps: int
    budget: int
    seed: int
    uncertainty_weight: float = 0.5
    layouts: tuple[str, ...] = ()
    confirm: int = 5


def plan(budget: int, missions: int, runs: int, confirm: int) -> tuple[int, int]:
    """(search trials, total runs) a budget buys.

    Each trial flies every mission `runs` times; the confirmation flies trial 0 and the `confirm`
    best candidates again on fresh runs.
    """
    per_trial = missions * runs
    reserved = (confirm + 1) * per_trial if confirm > 0 else 0
    trials = (budget - reserved) // per_trial if per_trial > 0 else 0
    if trials < max(2, confirm + 1):
        raise ValueError(
            f"--budget {budget} runs buys {max(trials, 0)} trial(s) of {per_trial} runs ({missions} "
            f"missions x {runs} runs) after {reserved} runs for confirming {confirm} candidates: need at "
            f"least {max(2, confirm + 1)} (the current weights and the candidates to confirm)"
        )
    return trials, trials * per_trial + reserved


class Trial(msgspec.Struct):
    """One row of the study's history: a candidate's weights, its score and its per-mission means.

    The score is its `Score` against trial 0 on the search runs (relative differences with their t
    intervals); the per-mission means are those of each metric; once confirmed, the row holds the
    same on the fresh runs.
    """

    trial: int
    objective: float
    relative_target_time: float
    relative_target_time_low: float
    relative_target_time_high: float
    relative_uncertainty: float
    relative_uncertainty_low: float
    relative_uncertainty_high: float
    missions_sooner: int
    confirmation_objective: float | None
    weights: dict[str, float]
    per_mission: dict[str, list[float]]
    confirmation_per_mission: dict[str, list[float]] | None = None


HISTORY_EXTRA = ("weights", "per_mission", "confirmation_per_mission")  # not columns of history.csv


class Chosen(msgspec.Struct, frozen=True):
    """The chosen trial and the `[algorithm]` entries its weights change (weights.toml)."""

    trial: int
    objective: float
    confirmation_objective: float | None
    algorithm: dict[str, Any]


class Study(msgspec.Struct, frozen=True):
    """What study.json holds: the setup, the runs, the search space and the trials.

    That is the setup, the runs planned and used, the caller's metadata, the search space, the
    chosen trial and the whole history.
    """

    setup: Setup
    trials_planned: int
    runs_per_trial: int
    runs_used: int
    meta: dict[str, Any]
    space: tuple[Weight, ...]
    chosen: Chosen
    history: list[Trial]

    def to_json(self) -> dict[str, Any]:
        """study.json's content: the setup's fields and the metadata at the top level."""
        return {
            **msgspec.to_builtins(self.setup),
            "objective": OBJECTIVE,
            "trials_planned": self.trials_planned,
            "runs_per_trial": self.runs_per_trial,
            "runs_used": self.runs_used,
            **self.meta,
            "space": msgspec.to_builtins(self.space),
            "chosen": msgspec.to_builtins(self.chosen),
            "history": msgspec.to_builtins(self.history),
        }


def tune(
    missions: Sequence[Mission],
    space: Sequence[Weight],
    setup: Setup,
    out: Path,
    executor: RunExecutor | None = None,
    meta: dict[str, Any] | None = None,
    advance: Callable[[], object] | None = None,
) -> Study | None:
    """Run the study, write its files into `out`, and return the `Study` (None when no trial flew).

    The study runs on `executor` (default: a local pool of every core, kept for the whole study)
    and writes weights.toml, history.csv, study.json and tune.png. An interrupted study writes what
    it has.

    The search scores each trial on runs 0..R-1 of every mission. The best `setup.confirm`
    candidates and trial 0 then fly runs R..2R-1 (new targets, CVT draws and starts), and the
    chosen weights are those with the lowest objective on these fresh runs (trial 0 if none is below
    0): a candidate that was only lucky on the search runs does not survive this.
    """
    if setup.algorithm not in ALGORITHMS:
        raise ValueError(f"unknown algorithm {setup.algorithm!r}; choose from {', '.join(ALGORITHMS)}")
    check_space(space, missions)
    trials, _ = plan(setup.budget, len(missions), setup.runs, setup.confirm)
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
        sampler = optuna.samplers.TPESampler(seed=setup.seed, multivariate=True)
    study = optuna.create_study(direction="minimize", sampler=sampler)
    current = {w.field: current_value(missions[0], w.field) for w in space}
    distributions = {w.field: _distribution(w, current[w.field]) for w in space}
    study.enqueue_trial(current)
    history: list[Trial] = []
    reference = np.empty(0)
    out.mkdir(parents=True, exist_ok=True)
    try:
        with nullcontext(executor) if executor else open_executor(keep=True) as runner:

            def fly(values: Mapping[str, float], first_run: int, label: str) -> np.ndarray:
                candidates = [apply_weights(m, weights_table(m, values), label) for m in missions]
                specs = specs_grid(
                    candidates, [setup.algorithm], setup.runs, setup.steps, setup.layouts, first_run
                )
                got = measure(specs, runner, advance)
                return got.reshape(len(missions), setup.runs, len(METRICS))

            for number in range(trials):
                trial = study.ask(distributions)
                values = {f: _rounded(v) for f, v in trial.params.items()}
                got = fly(values, 0, f"trial {number}")
                reference = got if number == 0 else reference
                s = score(got, reference, setup.uncertainty_weight)
                study.tell(trial, s.objective)
                history.append(_row(number, values, s, got))
                _write_history(out / "history.csv", history, space)
            if setup.confirm:
                fresh = fly(history[0].weights, setup.runs, "trial 0, confirmation")
                history[0].confirmation_objective = 0.0
                history[0].confirmation_per_mission = _means(fresh)
                for row in sorted(history[1:], key=lambda r: r.objective)[: setup.confirm]:
                    got = fly(row.weights, setup.runs, f"trial {row.trial}, confirmation")
                    row.confirmation_objective = score(got, fresh, setup.uncertainty_weight).objective
                    row.confirmation_per_mission = _means(got)
                    _write_history(out / "history.csv", history, space)
    finally:
        result = _finish(out, history, space, missions[0], setup, trials, meta or {}) if history else None
    return result


def _row(number: int, values: dict[str, float], s: Score, got: np.ndarray) -> Trial:
    t, u = s.target_time, s.uncertainty
    return Trial(
        number,
        s.objective,
        t.estimate,
        t.low,
        t.high,
        u.estimate,
        u.low,
        u.high,
        s.wins,
        None,
        values,
        _means(got),
    )


def _means(got: np.ndarray) -> dict[str, list[float]]:
    """Each metric's mean over the runs of each mission."""
    return {metric: got[:, :, q].mean(axis=1).tolist() for q, metric in enumerate(METRICS)}


def chosen_trial(history: Sequence[Trial]) -> Trial:
    """The confirmed trial with the lowest objective on the fresh runs (trial 0 scores 0 there).

    Without a confirmation, it is the trial with the lowest objective.
    """
    confirmed = [(r.confirmation_objective, r) for r in history if r.confirmation_objective is not None]
    if confirmed:
        return min(confirmed, key=lambda c: (c[0], c[1].trial))[1]
    return min(history, key=lambda r: (r.objective, r.trial))


def _write_history(path: Path, history: list[Trial], space: Sequence[Weight]) -> None:
    scalar = [k for k in Trial.__struct_fields__ if k not in HISTORY_EXTRA]
    with path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow([*scalar, *(s.field for s in space)])
        for row in history:
            w.writerow([*(getattr(row, k) for k in scalar), *(row.weights[s.field] for s in space)])


def _finish(
    out: Path,
    history: list[Trial],
    space: Sequence[Weight],
    mission: Mission,
    setup: Setup,
    trials: int,
    meta: dict[str, Any],
) -> Study:
    """Write weights.toml (the chosen trial's), study.json and tune.png."""
    chosen = chosen_trial(history)
    table = weights_table(mission, chosen.weights)
    per_trial = len(chosen.per_mission[METRICS[0]]) * setup.runs
    confirmed = sum(r.confirmation_objective is not None for r in history)
    used = (len(history) + confirmed) * per_trial
    if chosen.trial == 0:
        verdict = "no candidate beat the weights before" + (" on fresh runs" if confirmed else "")
        verdict += ": these are they"
    else:
        verdict = (
            f"chosen: trial {chosen.trial}, objective {chosen.objective:+.4f} on the search runs (mean "
            f"target time {100 * chosen.relative_target_time:+.1f} %, mean uncertainty "
            f"{100 * chosen.relative_uncertainty:+.1f} %)"
        )
        if chosen.confirmation_objective is not None:
            verdict += f", {chosen.confirmation_objective:+.4f} on fresh runs"
    header = [
        f"uavsearch tune: {setup.algorithm}, {len(history)} of {trials} trials x {per_trial} runs, "
        f"{max(confirmed - 1, 0)} confirmed on fresh runs ({used} of a budget of {setup.budget} runs), "
        f"{setup.steps} steps per run, seed {setup.seed}",
        "objective: mean over the training missions of the relative change of the mean target time "
        f"+ {setup.uncertainty_weight} x that of the mean uncertainty, against trial 0 (the weights before)",
        verdict,
        "The lines below [algorithm] go into a mission file's [algorithm] section.",
    ]
    snippet = "".join(f"# {line}\n" for line in header) + "[algorithm]\n" + toml_snippet(table)
    (out / "weights.toml").write_text(snippet)
    best = Chosen(chosen.trial, chosen.objective, chosen.confirmation_objective, table)
    result = Study(setup, trials, per_trial, used, meta, tuple(space), best, history)
    write_json(out / "study.json", result.to_json())
    plots.plot_study(out / "tune.png", history, f"tune {setup.algorithm}")
    return result
