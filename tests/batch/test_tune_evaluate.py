"""`uavsearch tune` and `uavsearch evaluate` end to end on a tiny budget (real runs of the batch
engine in worker processes), their files checked against each other and recomputed by hand; the
search space's table; bad input as clear errors."""

from __future__ import annotations

import csv
import json
import multiprocessing
import tomllib
from pathlib import Path

import msgspec
import numpy as np
import pytest

from companion.batch.executors import LocalPool
from companion.batch.generate import Family, generate
from companion.batch.montecarlo import RunSpec, run_specs
from companion.batch.paired import apply_weights, load_weights
from companion.batch.stats import mean_ci, wilson
from companion.batch.tune import (
    SPACE,
    Setup,
    Weight,
    check_space,
    current_value,
    load_space,
    select,
    toml_snippet,
    tune,
    weights_table,
)
from companion.cli.main import main
from companion.contracts.mission import Algorithm, MissionError
from companion.core.feasibility import load_mission
from tests.cli import uavsearch

ROOT = Path(__file__).resolve().parents[2]
SCENARIO = load_mission(ROOT / "mission_files/scenario1.toml")
TINY = ("--uavs", "2-3", "--across", "800-1200", "--targets", "5-6", "--steps", "30")


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open() as f:
        return list(csv.DictReader(f))


def test_weights_table_keeps_pairs_and_nested_tables_whole() -> None:
    values = {"beta.1": 0.5, "kappa": 2.0, "pheromone.weight": 3.0}
    table = weights_table(SCENARIO, values)
    assert table == {
        "beta": [1.0, 0.5],
        "kappa": 2.0,
        "pheromone": {"deposit": 1.0, "evaporation": 0.1, "diffusion": 0.2, "weight": 3.0},
    }
    snippet = toml_snippet(table)
    assert "pheromone = { deposit = 1.0," in snippet
    parsed = tomllib.loads("[algorithm]\n" + snippet)["algorithm"]
    m = apply_weights(SCENARIO, parsed, "snippet")
    assert m.algorithm.beta == (1.0, 0.5) and m.algorithm.kappa == 2.0
    assert m.algorithm.pheromone.weight == 3.0 and m.algorithm.pheromone.evaporation == 0.1
    assert SCENARIO.algorithm.beta == Algorithm().beta  # the mission itself is untouched
    assert current_value(m, "pheromone.weight") == 3.0 and current_value(m, "beta.0") == 1.0
    with pytest.raises(ValueError, match="'gamma' is not a field"):
        current_value(m, "gamma")
    with pytest.raises(MissionError, match=r"^w\.toml: algorithm\.v_max: Expected `float` <= 1"):
        apply_weights(SCENARIO, {"v_max": 1.5}, "w.toml")
    with pytest.raises(MissionError, match="unknown field `kapa`"):
        apply_weights(SCENARIO, {"kapa": 1.0}, "w.toml")


def test_the_default_space_holds_the_current_weights_and_each_algorithm_tunes_what_it_reads() -> None:
    check_space(SPACE, [SCENARIO])
    proposed = {w.field for w in select(SPACE, "proposed", None)}
    assert {"kappa", "v_max", "c_max", "beta.1", "comm_cost_cap", "delta.1", "chi.1"} == proposed
    assert {w.field for w in select(SPACE, "no-ta", None)} == {"chi.1"}
    assert {w.field for w in select(SPACE, "pheromone", None)} == {
        "chi.1", "pheromone.weight", "pheromone.evaporation", "pheromone.diffusion"
    }  # fmt: skip
    assert {w.field for w in select(SPACE, "pheromone", ["pheromone.weight"])} == {"pheromone.weight"}
    with pytest.raises(ValueError, match=r"proposed does not read pheromone\.weight"):
        select(SPACE, "proposed", ["kappa", "pheromone.weight"])
    with pytest.raises(ValueError, match="no search-space row for kapa"):
        select(SPACE, "proposed", ["kapa"])
    with pytest.raises(ValueError, match="outside the range"):
        check_space([Weight("kappa", 5.0, 10.0)], [SCENARIO])
    with pytest.raises(ValueError, match="the missions disagree"):
        check_space([Weight("kappa", 1.0, 10.0)], [SCENARIO, SCENARIO.with_algorithm(kappa=4.0)])
    with pytest.raises(ValueError, match="not a field"):
        check_space([Weight("kappa.2", 1.0, 10.0)], [SCENARIO])


def test_a_space_file_names_mission_fields(tmp_path: Path) -> None:
    good = tmp_path / "space.toml"
    good.write_text(
        '[kappa]\nlow = 1\nhigh = 9\nlog = true\n\n["pheromone.diffusion"]\nlow = 0.0\nhigh = 0.4\n'
        'read_by = ["pheromone"]\n'
    )
    space = load_space(good)
    assert space == (
        Weight("kappa", 1.0, 9.0, True),
        Weight("pheromone.diffusion", 0.0, 0.4, False, ("pheromone",)),
    )
    bad = tmp_path / "bad.toml"
    bad.write_text("[kappa]\nlow = 1\n")
    with pytest.raises(MissionError, match=r"kappa.*high"):
        load_space(bad)


def _objective(per_mission: dict, reference: dict) -> float:
    """J by hand (tune.OBJECTIVE, lambda = 0.5) from per-mission means."""
    t0, u0 = np.array(reference["target_time"]), np.array(reference["mean_uncertainty"])
    t, u = np.array(per_mission["target_time"]), np.array(per_mission["mean_uncertainty"])
    return float(np.mean((t - t0) / np.maximum(t0, 1) + 0.5 * (u - u0) / u0))


def test_tune_end_to_end_on_a_tiny_budget(tmp_path: Path) -> None:
    """3 missions x 1 run per trial, a budget of 24 runs: 5 trials, then trial 0 and the 2 best
    candidates again on fresh runs (9 runs). Trial 0 is the current weights; every objective is
    recomputed from the per-mission means; the chosen trial is the best on the fresh runs and its
    weights are the snippet; the same study in this process on one worker gives the same history."""
    out = tmp_path / "tune"
    args = ("--missions", "3", "--seed", "8", "--runs", "1", "--budget", "24", "--confirm", "2", *TINY)
    proc = uavsearch("tune", *args, "--out", str(out), "--workers", "2", "--quiet")
    assert proc.returncode == 0, proc.stderr
    history = _rows(out / "history.csv")
    assert [int(r["trial"]) for r in history] == list(range(5))
    first = history[0]
    assert float(first["objective"]) == 0.0
    default = Algorithm()  # trial 0: the generated missions' weights, the defaults
    assert (float(first["kappa"]), float(first["v_max"]), float(first["beta.1"])) == (
        default.kappa,
        default.v_max,
        default.beta[1],
    )
    assert len({r["kappa"] for r in history}) == 5  # TPE proposed new candidates
    study = json.loads((out / "study.json").read_text())
    assert study["runs_used"] == 24 and study["trials_planned"] == 5 and study["seed"] == 8
    trials = study["history"]
    for t in trials:
        assert t["objective"] == pytest.approx(
            _objective(t["per_mission"], trials[0]["per_mission"]), abs=1e-12
        )
    confirmed = [t for t in trials if t["confirmation_objective"] is not None]
    best_two = sorted(trials[1:], key=lambda t: t["objective"])[:2]
    assert [t["trial"] for t in confirmed] == sorted([0] + [t["trial"] for t in best_two])
    fresh = trials[0]["confirmation_per_mission"]
    assert fresh != trials[0]["per_mission"]  # other runs: other targets
    for t in confirmed:
        by_hand = _objective(t["confirmation_per_mission"], fresh)
        assert t["confirmation_objective"] == pytest.approx(by_hand, abs=1e-12)
    chosen = min(confirmed, key=lambda t: (t["confirmation_objective"], t["trial"]))
    assert study["chosen"]["trial"] == chosen["trial"]
    weights = load_weights(out / "weights.toml")
    mission = load_mission(out / "missions" / "generated-8-000.toml")
    assert weights == weights_table(mission, chosen["weights"])
    assert apply_weights(mission, weights, "weights.toml").algorithm.kappa == chosen["weights"]["kappa"]
    assert (out / "tune.png").read_bytes()[:4] == b"\x89PNG"
    assert "[algorithm]" in proc.stdout

    again = tmp_path / "again"
    missions = [
        m for m, _ in generate(3, 8, Family(uavs=(2, 3), across=(800, 1200), targets=(5, 6), steps=30))
    ]
    setup = Setup("proposed", 1, 30, 24, 8, confirm=2)
    result = tune(missions, select(SPACE, "proposed", None), setup, again, LocalPool(1))
    for key in ("objective", "weights", "confirmation_objective"):
        assert result is not None
        assert [msgspec.to_builtins(t)[key] for t in result.history] == [t[key] for t in trials]


def test_evaluate_end_to_end_on_a_tiny_budget(tmp_path: Path) -> None:
    """3 missions x 3 algorithms x 2 runs; evaluate.json's per-mission and overall figures
    recomputed from runs.csv."""
    out = tmp_path / "evaluate"
    first, second = tmp_path / "a.toml", tmp_path / "b.toml"
    first.write_text("[algorithm]\nkappa = 2.5\nbeta = [1.0, 0.5]\n")
    second.write_text("[algorithm]\nkappa = 4.0\npheromone = { weight = 1.5 }\n")
    weights = ("--weights", str(first), str(second))
    proc = uavsearch(
        "evaluate",
        "--missions",
        "3",
        "--seed",
        "4",
        "--runs",
        "2",
        *TINY,
        *weights,
        "--out",
        str(out),
        "--quiet",
    )
    assert proc.returncode == 0, proc.stderr
    assert sorted(p.name for p in (out / "missions").iterdir()) == [
        f"generated-4-00{i}.toml" for i in range(3)
    ]
    runs = _rows(out / "runs.csv")
    assert len(runs) == 3 * 3 * 2
    for r in runs:  # generated missions have the paper's sensor: the first look confirms
        assert float(r["confirm_time"]) == pytest.approx(float(r["target_time"]))
        assert r["false_confirmations"] == "0"
    value = {(r["mission"], r["algorithm"], int(r["run"])): r for r in runs}
    result = json.loads((out / "evaluate.json").read_text())
    assert result["meta"]["generated"]["seed"] == 4 and result["meta"]["runs"] == 2
    assert [w["algorithm"] for w in result["meta"]["weights"]] == [
        {"kappa": 2.5, "beta": [1.0, 0.5]},
        {"kappa": 4.0, "pheromone": {"weight": 1.5}},
    ]
    for metric in ("target_time", "mean_uncertainty"):
        for baseline in ("no-ta", "pheromone"):
            means = []
            for m in (f"generated-4-00{i}" for i in range(3)):
                d = [
                    float(value[m, "proposed", r][metric]) - float(value[m, baseline, r][metric])
                    for r in (0, 1)
                ]
                row = next(
                    x for x in result["missions"]
                    if (x["mission"], x["baseline"], x["metric"]) == (m, baseline, metric)
                )  # fmt: skip
                ci = mean_ci(d)
                assert (row["difference"], row["difference_low"]) == pytest.approx(
                    (ci.estimate, ci.low), rel=1e-7, abs=1e-9
                )
                means.append(row["difference"])
            o = next(x for x in result["overall"] if (x["baseline"], x["metric"]) == (baseline, metric))
            wins = sum(d < 0 for d in means)
            assert o["wins"] == wins and o["win_rate_high"] == pytest.approx(wilson(wins, 3).high)
            assert o["difference"] == pytest.approx(np.mean(means))
    assert {r["baseline"] for r in _rows(out / "overall.csv")} == {"no-ta", "pheromone"}
    # the dense / thin halves: the missions split at the median area per UAV (shoelace by hand)
    per_uav = {}
    for info in result["mission_info"]:
        m = load_mission(out / "missions" / f"{info['mission']}.toml")
        (x, y) = np.array(m.region.polygon).T
        area = sum(x[i - 1] * y[i] - x[i] * y[i - 1] for i in range(len(x))) / 2e6
        assert info["area_km2"] == pytest.approx(abs(area)) and info["uavs"] == m.n_uavs
        per_uav[info["mission"]] = abs(area) / m.n_uavs
    median = float(np.median(list(per_uav.values())))
    for o in result["overall"]:
        key = (o["baseline"], o["metric"])
        halves = [h for h in result["by_density"] if (h["baseline"], h["metric"]) == key]
        assert sum(h["missions"] for h in halves) == 3 and sum(h["wins"] for h in halves) == o["wins"]
        for h in halves:
            thin = h["half"] == "thin"
            d = [
                x["difference"]
                for x in result["missions"]
                if (x["baseline"], x["metric"]) == key and (per_uav[x["mission"]] > median) == thin
            ]
            assert h["missions"] == len(d) and h["difference"] == pytest.approx(np.mean(d))
    assert (out / "evaluate.png").read_bytes()[:4] == b"\x89PNG"
    assert (out / "evaluate_density.png").read_bytes()[:4] == b"\x89PNG"
    assert "overall (3 missions x 2 runs)" in proc.stdout


def _in_process(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch, *args: str
) -> tuple[int, str]:
    """`uavsearch ARGS` in this process, from the repository's root: exit code and stderr."""
    monkeypatch.chdir(ROOT)
    try:
        code = main(list(args))
    except SystemExit as exc:  # argparse's usage errors
        code = exc.code
    return code, capsys.readouterr().err


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (("evaluate", "--runs", "2"), "give --missions N and --seed S"),
        (("evaluate", "--missions", "1", "--seed", "1", "--runs", "1"), "--runs must be at least 2"),
        (("tune", "--missions", "2", "--seed", "1", "--budget", "13"), "need at least 6"),
        (
            ("tune", "--missions", "1", "--seed", "1", "--budget", "9", "--params", "gamma"),
            "no search-space row",
        ),
        (("evaluate", "--mission-dir", "mission_files", "--weights", "README.md"), "README.md: (syntax)"),
        (("evaluate", "--missions", "1", "--seed", "1", "--weights", "nowhere.toml"), "nowhere.toml: (file)"),
    ],
)
def test_bad_input_is_a_clear_error(
    args: tuple[str, ...],
    message: str,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    code, err = _in_process(capsys, monkeypatch, *args, "--quiet", "--out", str(tmp_path))
    assert code == 2, err  # an unexpected exception would fail the test with its traceback
    assert message in err
    assert not (tmp_path / "missions").exists()  # checked before anything is generated or written


def test_an_unwritable_output_folder_is_a_clear_error(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    args = ("evaluate", "--missions", "1", "--seed", "1", "--out", "/dev/null/never", "--quiet")
    code, err = _in_process(capsys, monkeypatch, *args)
    assert code == 2, err
    assert "error: --out /dev/null/never:" in err


def test_tune_a_space_file_on_a_folder_of_missions(tmp_path: Path) -> None:
    """A weight the default space lacks (an integer one, n_g) is tuned from a --space file, on the
    mission files of a folder (the scenario files, which share n_g = 50)."""
    space = tmp_path / "space.toml"
    space.write_text("[n_g]\nlow = 10\nhigh = 90\n")
    out = tmp_path / "tune"
    budget = str(3 * len(list((ROOT / "mission_files").glob("*.toml"))))  # 3 trials
    args = (
        "--mission-dir",
        "mission_files",
        "--space",
        str(space),
        "--steps",
        "15",
        "--budget",
        budget,
        "--confirm",
        "0",
    )
    proc = uavsearch("tune", *args, "--out", str(out), "--quiet", "--workers", "1")
    assert proc.returncode == 0, proc.stderr
    history = _rows(out / "history.csv")
    assert history[0]["n_g"] == "50"
    assert all(r["n_g"].isdigit() and 10 <= int(r["n_g"]) <= 90 for r in history)
    assert len(history) == 3
    table = load_weights(out / "weights.toml")
    assert set(table) == {"n_g"} and isinstance(table["n_g"], int)
    assert not (out / "missions").exists()  # a folder's missions are not copied


def test_a_kept_local_pool_serves_every_map_and_leaves_no_process() -> None:
    """`LocalPool(keep=True)` (a tune's trials): the same worker processes run every map, the
    results are those of a fresh pool, and `close` ends them."""
    specs = [RunSpec(SCENARIO, 1, r, 4) for r in range(4)]
    before = {p.pid for p in multiprocessing.active_children()}
    pool = LocalPool(2, keep=True)
    first = [r.uncertainty for r in run_specs(specs, executor=pool)]
    workers = {p.pid for p in multiprocessing.active_children()} - before
    second = [r.uncertainty for r in run_specs(specs, executor=pool)]
    assert len(workers) == 2
    assert {p.pid for p in multiprocessing.active_children()} - before == workers
    fresh = [r.uncertainty for r in run_specs(specs, executor=LocalPool(2))]
    for a, b, c in zip(first, second, fresh, strict=True):
        np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(a, c)
    pool.close()
    assert not {p.pid for p in multiprocessing.active_children()} - before
