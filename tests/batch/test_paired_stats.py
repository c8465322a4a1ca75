"""The statistics of `uavsearch evaluate` and `uavsearch tune` against values computed by hand on
small synthetic inputs: the t interval of a mean of paired differences, the Wilson interval, the
per-mission and overall paired comparison, and the tuning objective."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import msgspec
import numpy as np
import pytest

from companion.batch.heldout import paired_table
from companion.batch.paired import specs_grid
from companion.batch.stats import mean_ci, wilson
from companion.batch.tune import score
from companion.core.feasibility import load_mission

ROOT = Path(__file__).resolve().parents[2]
T3 = 3.182446305  # Student t, 0.975 quantile, 3 degrees of freedom
T1 = 12.706204736  # ... 1 degree of freedom


def test_mean_ci_is_the_student_t_interval() -> None:
    # mean 2.5, s = sqrt(5/3) = 1.2909944, s / sqrt(4) = 0.6454972, half-width 3.1824463 * 0.6454972
    ci = mean_ci([1.0, 2.0, 3.0, 4.0])
    assert ci.estimate == 2.5 and ci.n == 4
    assert ci.low == pytest.approx(2.5 - T3 * 0.6454972244, abs=1e-9)
    assert ci.high == pytest.approx(4.5542603, abs=1e-7)
    same = mean_ci([2.0, 2.0, 2.0])
    assert (same.low, same.high) == (2.0, 2.0)
    one = mean_ci([5.0])
    assert one.estimate == 5.0 and math.isnan(one.low) and math.isnan(one.high)
    with pytest.raises(ValueError):
        mean_ci([])


def test_wilson_interval_matches_hand_computed_values() -> None:
    # the published 95 % Wilson intervals (Newcombe 1998, method 3) to their 4 decimals
    ci = wilson(8, 10)
    assert ci.estimate == 0.8
    assert (ci.low, ci.high) == pytest.approx((0.4902, 0.9433), abs=5e-5)
    none = wilson(0, 10)  # [0, z^2/n / (1 + z^2/n)]
    assert none.low == 0.0 and none.high == pytest.approx(0.2775, abs=5e-5)
    every = wilson(10, 10)
    assert (every.low, every.high) == pytest.approx((1 - 0.2775, 1.0), abs=5e-5)
    assert (wilson(2, 2).low, wilson(1, 2).low, wilson(1, 2).high) == pytest.approx(
        (0.3424, 0.0945, 0.9055), abs=5e-5
    )
    for bad in ((3, 2), (-1, 4), (0, 0)):
        with pytest.raises(ValueError):
            wilson(*bad)


def _synthetic() -> np.ndarray:
    """values[mission, algorithm (proposed, no-ta, pheromone), run, metric]: 2 missions, 2 runs."""
    v = np.zeros((2, 3, 2, 2))
    v[0, :, :, 0] = [[10, 20], [14, 22], [9, 19]]  # target time, mission A
    v[1, :, :, 0] = [[30, 40], [31, 45], [35, 41]]  # mission B
    v[:, :, :, 1] = 0.3  # mean uncertainty: the same for every algorithm
    return v


def _row(rows: Sequence[msgspec.Struct], **match: str) -> dict[str, Any]:
    (found,) = [r for r in msgspec.to_builtins(rows) if all(r[k] == v for k, v in match.items())]
    return found


def test_paired_table_per_mission_and_overall() -> None:
    t = paired_table(_synthetic(), ("proposed", "no-ta", "pheromone"), ["A", "B"])
    assert len(t.missions) == 2 * 2 * 2 and len(t.overall) == 2 * 2
    # no-ta, mission A: differences -4, -2 -> mean -3, s = sqrt(2), half-width t_1 * sqrt(2) / sqrt(2)
    a = _row(t.missions, mission="A", baseline="no-ta", metric="target_time")
    assert (a["proposed"], a["baseline_value"], a["difference"]) == (15.0, 18.0, -3.0)
    assert (a["difference_low"], a["difference_high"]) == pytest.approx((-3 - T1, -3 + T1))
    o = _row(t.overall, baseline="no-ta", metric="target_time")
    assert (o["difference"], o["difference_low"], o["difference_high"]) == (-3.0, -3.0, -3.0)
    assert o["relative_difference"] == pytest.approx(-(3 / 18 + 3 / 38) / 2)
    assert (o["wins"], o["ties"], o["losses"]) == (2, 0, 0)
    assert o["win_rate"] == 1.0 and o["win_rate_low"] == pytest.approx(0.3424, abs=5e-5)  # Wilson, 2 of 2
    assert o["significantly_better"] == 0  # each mission's interval holds 0
    # pheromone: A +1, +1 (an interval [1, 1]: significantly worse); B -5, -1 (mean -3, s = 2 sqrt(2))
    b = _row(t.missions, mission="B", baseline="pheromone", metric="target_time")
    assert (b["difference_low"], b["difference_high"]) == pytest.approx((-3 - 2 * T1, -3 + 2 * T1))
    o = _row(t.overall, baseline="pheromone", metric="target_time")
    assert o["difference"] == -1.0  # mean of the mission means 1 and -3, s = 2 sqrt(2), se = 2
    assert (o["difference_low"], o["difference_high"]) == pytest.approx((-1 - 2 * T1, -1 + 2 * T1))
    assert (o["wins"], o["losses"], o["significantly_worse"], o["win_rate"]) == (1, 1, 1, 0.5)
    u = _row(t.overall, baseline="no-ta", metric="mean_uncertainty")
    assert (u["wins"], u["ties"], u["losses"], u["win_rate"], u["difference"]) == (0, 2, 0, 0.0, 0.0)


def test_paired_table_rejects_a_misshapen_input() -> None:
    with pytest.raises(ValueError):
        paired_table(np.zeros((2, 1, 2, 2)), ("proposed",), ["A", "B"])


def test_tuning_objective_is_the_mean_relative_paired_change() -> None:
    reference = np.array([[[8, 0.5], [12, 0.5]], [[40, 0.2], [40, 0.2]]], dtype=float)  # T0 = 10, 40
    candidate = np.array([[[9, 0.45], [9, 0.45]], [[44, 0.2], [44, 0.2]]], dtype=float)  # T = 9, 44
    s = score(candidate, reference, 0.5)
    # time: -0.1, +0.1; uncertainty: -0.1, 0 -> J = mean(-0.1 - 0.05, 0.1 + 0) = -0.025
    assert s.objective == pytest.approx(-0.025)
    assert s.target_time.estimate == pytest.approx(0.0) and s.uncertainty.estimate == pytest.approx(-0.05)
    assert s.wins == 1
    assert score(reference, reference, 0.5).objective == 0.0
    tiny = np.array([[[0.5, 0.5]]])  # a target time under one step is floored at one step
    assert score(tiny + np.array([[[1.0, 0.0]]]), tiny, 0.0).objective == pytest.approx(1.0)


def test_every_candidate_and_algorithm_flies_the_same_runs() -> None:
    """Common random numbers: spec i of any two candidates (or algorithms) has the same mission
    instance: seed, run index and start layout."""
    m = load_mission(ROOT / "mission_files/scenario2.toml").with_seed(17)
    other = m.with_algorithm(kappa=9.0)
    for layouts in ((), ("edge", "clustered")):
        a = specs_grid([m, m], ["proposed", "no-ta"], 3, 50, layouts)
        b = specs_grid([other, other], ["proposed", "no-ta"], 3, 50, layouts)
        assert len(a) == len(b) == 2 * 2 * 3
        for x, y in zip(a, b, strict=True):
            assert (x.seed, x.run, x.steps, x.mission.vehicles) == (17, y.run, 50, y.mission.vehicles)
            assert x.mission.algorithm.name == y.mission.algorithm.name
        for i in range(0, len(a), 6):  # one mission: its proposed runs, then its no-ta runs
            for r in range(3):
                p, n = a[i + r], a[i + 3 + r]
                assert (p.mission.algorithm.name, n.mission.algorithm.name) == ("proposed", "no-ta")
                assert (p.seed, p.run, p.mission.vehicles) == (n.seed, n.run, n.mission.vehicles)
        starts = {tuple((v.x, v.y) for v in s.mission.vehicles) for s in a}
        assert len(starts) == (3 if layouts else 1)  # one layout per run, or the mission's
