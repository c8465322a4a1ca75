"""Eq. 28 virtual force (and the link cost of eq. 17): zero in the band, growing towards the limits."""

from __future__ import annotations

import math

import numpy as np
import pytest

from companion.core.potential import link_cost, safety_cost, virtual_force

R_C, R_C_ATTR, R_S, R_S_REP = 1000.0, 700.0, 60.0, 120.0


def force(d: float | np.ndarray) -> np.ndarray:
    return virtual_force(d, R_C, R_C_ATTR, R_S, R_S_REP)


def test_zero_in_the_band() -> None:
    d = np.linspace(R_S_REP, R_C_ATTR, 1001)
    assert np.all(force(d) == 0.0)


def test_values_at_chosen_distances() -> None:
    # attraction: d = 850 -> (850-700)/(1000-850) = 1 -> e - 1 = 1.7182818
    #             d = 900 -> 200/100 = 2 -> e^2 - 1 = 6.3890561
    #             d = 740 -> 40/260 = 0.15384615 -> 0.16631144
    assert float(link_cost(850.0, R_C, R_C_ATTR)) == pytest.approx(1.7182818, rel=1e-7)
    assert float(force(900.0)) == pytest.approx(6.3890561, rel=1e-7)
    assert float(force(740.0)) == pytest.approx(0.16631144, rel=1e-7)
    # repulsion: d = 90 -> (120-90)/(90-60) = 1 -> 1.7182818; d = 80 -> 40/20 = 2 -> 6.3890561
    assert float(safety_cost(90.0, R_S, R_S_REP)) == pytest.approx(1.7182818, rel=1e-7)
    assert float(force(80.0)) == pytest.approx(6.3890561, rel=1e-7)


def test_monotone_towards_the_limits() -> None:
    out = np.linspace(R_C_ATTR, 1600.0, 2000)
    assert np.all(np.diff(force(out)) >= 0)
    assert force(990.0) > force(950.0) > force(900.0) > 0
    inn = np.linspace(0.0, R_S_REP, 2000)
    assert np.all(np.diff(force(inn)) <= 0)
    assert force(65.0) > force(70.0) > force(100.0) > 0


def test_huge_near_and_beyond_the_limits() -> None:
    # e^30 - 1 = 1.0686e13 is the barrier at the limits; it keeps growing past them.
    barrier = math.expm1(30.0)
    for d in (999.99, 1000.0, 1001.0, 1500.0, 60.001, 60.0, 30.0, 0.0):
        assert float(force(d)) >= 0.999 * barrier, d
    assert force(1500.0) > force(1000.0)
    assert force(0.0) > force(60.0)
    assert np.all(np.isfinite(force(np.array([0.0, 1e5]))))


def test_vectorised_matches_scalar() -> None:
    d = np.array([50.0, 100.0, 400.0, 850.0, 1200.0])
    assert np.array_equal(force(d), np.array([float(force(float(x))) for x in d]))
