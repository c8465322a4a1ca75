"""Eqs. 15-18 (income, time and communication costs, reward) and eqs. 20-21 (reevaluation)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from companion.core.cvt import describe
from companion.core.routes import STRAIGHT
from companion.core.tasks import (
    CostWeights,
    bid_rewards,
    communication_costs,
    keep_task,
    task_completion,
    task_costs,
    time_cost,
)

# beta_1 = 1, beta_2 = 2, kappa = 3, S_A = 1000 m^2, diagonal 50 m, R_c = 1000, R'_c = 700, cap 3
W = CostWeights(1.0, 2.0, 3.0, 1000.0, 50.0, 1000.0, 700.0, 3.0)
GENS = np.array([[300.0, 400.0], [0.0, 0.0]])
AREAS = np.array([2000.0, 500.0])
HERE = np.array([0.0, 0.0])
# MST neighbours: A at (0, 1000) and B at (0, -850)
NBRS = np.array([[0.0, 1000.0], [0.0, -850.0]])


def test_time_cost() -> None:
    # task 0: d = 500 -> 500 / 50 + 3 * 2000 / 1000 = 10 + 6 = 16
    # task 1: d = 0   -> 0 + 3 * 500 / 1000 = 1.5
    assert time_cost(HERE, GENS, AREAS, W, STRAIGHT, 0) == pytest.approx([16.0, 1.5])


def test_communication_cost_with_cap() -> None:
    # task 0 (300, 400): A at sqrt(300^2 + 600^2) = 670.8 <= R'_c -> 0;
    #                    B at sqrt(300^2 + 1250^2) = 1285.5 >= R_c -> capped at e^3 - 1 = 19.085537
    # task 1 (0, 0):     A at 1000 = R_c -> capped at 19.085537;
    #                    B at 850 -> (850 - 700) / (1000 - 850) = 1 -> e - 1 = 1.718282
    cap = 19.085537
    assert communication_costs(NBRS, GENS, W)[0] == pytest.approx([cap, cap + 1.718282], rel=1e-6)
    # no MST neighbours: no communication cost
    assert communication_costs(np.zeros((0, 2)), GENS, W)[0].tolist() == [0.0, 0.0]
    # a neighbour inside R'_c of both generators costs nothing
    assert communication_costs(np.array([[100.0, 100.0]]), GENS, W)[0].tolist() == [0.0, 0.0]


def test_comm_cap_saturates_each_neighbour_term() -> None:
    far = np.array([[5000.0, 0.0]])
    for cap in (1.0, 3.0, 10.0):
        w = W._replace(comm_cap=cap)
        assert communication_costs(far, GENS, w)[0] == pytest.approx([math.expm1(cap)] * 2)
    # below the cap the term is the uncapped eq. 17 value: d = 900 -> e^2 - 1 = 6.389056 < e^3 - 1
    assert communication_costs(np.array([[900.0, 0.0]]), GENS[1:], W)[0][0] == pytest.approx(
        6.389056, rel=1e-6
    )


def test_task_costs() -> None:
    # C = beta_1 C^t + beta_2 C^c: task 0: 16 + 2 * 19.085537 = 54.171074
    #                              task 1: 1.5 + 2 * (19.085537 + 1.718282) = 43.107638
    costs = task_costs(HERE, NBRS, GENS, AREAS, W, STRAIGHT, 0)[0]
    assert costs == pytest.approx([54.171074, 43.107638], rel=1e-6)


def test_eq_21_cost_is_eq_18_without_the_cap() -> None:
    # below the cap both costs agree: one neighbour at 900 m of task 1 -> 1.5 + 2 (e^2 - 1)
    near = np.array([[900.0, 0.0]])
    assert task_costs(HERE, near, GENS[1:], AREAS[1:], W, STRAIGHT, 1)[1] == pytest.approx(
        task_costs(HERE, near, GENS[1:], AREAS[1:], W, STRAIGHT, 1)[0]
    )
    # d = 960 m: (960 - 700) / 40 = 6.5 -> e^6.5 - 1 = 664.1 > C_max 300, capped at e^3 - 1 in the auction
    edge = np.array([[960.0, 0.0]])
    strict = task_costs(HERE, edge, GENS[1:], AREAS[1:], W, STRAIGHT, 1)[1][0]
    assert strict == pytest.approx(1.5 + 2 * math.expm1(6.5), rel=1e-6)
    assert task_costs(HERE, edge, GENS[1:], AREAS[1:], W, STRAIGHT, 1)[0][0] == pytest.approx(
        1.5 + 2 * math.expm1(3.0), rel=1e-6
    )
    assert keep_task(0.1, task_costs(HERE, edge, GENS[1:], AREAS[1:], W, STRAIGHT, 1)[0][0], 0.85, 300.0)
    assert not keep_task(0.1, strict, 0.85, 300.0)
    # at or beyond R_c the link is lost: no C_max keeps the task
    for d in (1000.0, 1500.0, 5000.0):
        assert not keep_task(
            0.1, task_costs(HERE, np.array([[d, 0.0]]), GENS[1:], AREAS[1:], W, STRAIGHT, 1)[1][0], 0.85, 1e9
        )


def test_income_and_reward_on_a_tiny_tessellation() -> None:
    # four 40 m cells, tasks {0, 1} and {2, 3}; importance eta * Pr = 0.1, 0.2, 0.3, 0.4
    centres = np.array([[20.0, 20.0], [60.0, 20.0], [100.0, 20.0], [140.0, 20.0]])
    tess = describe(centres, np.array([[40.0, 20.0], [120.0, 20.0]]), np.array([0, 0, 1, 1]), 1600.0)
    eta, prior = np.array([0.2, 0.4, 0.6, 0.8]), np.full(4, 0.5)
    here, none = np.array([40.0, 20.0]), np.zeros((0, 2))

    def bids(covered: tuple[int, int] = (0, 0), c_max: float = 1e9, held: int = -1) -> np.ndarray:
        counts = np.array(covered, dtype=np.int64)
        tasks = (tess.labels, tess.cell_counts, tess.generators, tess.areas, tess.routes)
        return bid_rewards(eta, prior, counts, tasks, 0.85, c_max, here, none, W, held)

    # r_j = sum of eta Pr over V_j: 0.3 and 0.7; from (40, 20), no neighbours:
    # C^t = d / 50 + 3 * 3200 / 1000 = [0 + 9.6, 80/50 + 9.6] = [9.6, 11.2]
    # R = r / C = [0.3 / 9.6, 0.7 / 11.2] = [0.03125, 0.0625]
    assert bids() == pytest.approx([0.03125, 0.0625])
    # eq. 21's bidder bids nothing for a task covered beyond v_max, or costing more than C_max
    assert bids(covered=(2, 0)) == pytest.approx([0.0, 0.0625])
    assert bids(c_max=10.0) == pytest.approx([0.03125, 0.0])
    # holding a task, it bids only for tasks worth more (Algorithm 2's greedy bidder)
    assert bids(held=0) == pytest.approx([0.0, 0.0625])
    assert bids(held=1) == pytest.approx([0.0, 0.0])
    # every task complete: no bids at all
    assert bids(covered=(2, 2)).shape == (0,)


def test_task_completion() -> None:
    # eq. 20 as intended: covered share of the task's area
    assert task_completion(10, 50) == pytest.approx(0.2)
    assert task_completion(50, 50) == 1.0
    assert task_completion(0, 0) == 1.0  # an empty task is complete


def test_keep_task() -> None:
    # eq. 21: keep while v <= v_max and C <= C_max (both inclusive)
    assert keep_task(0.85, 300.0, 0.85, 300.0) is True
    assert keep_task(0.86, 10.0, 0.85, 300.0) is False
    assert keep_task(0.1, 300.1, 0.85, 300.0) is False
    assert keep_task(0.1, math.nan, 0.85, 300.0) is False
    assert keep_task(0.1, math.inf, 0.85, math.inf) is False
