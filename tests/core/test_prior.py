"""Eq. 1: the prior target probability, per centre and combined as 1 - prod(1 - p)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.core.prior import centre_probability, draw_targets, gain_for_peak, prior_map


def test_gain_for_peak() -> None:
    # K = peak * sqrt(2 pi) * sigma = 0.012 * 2.5066283 * 250 = 7.5198848
    assert gain_for_peak(0.012, 250.0) == pytest.approx(7.5198848, rel=1e-7)


def test_single_centre_values_at_known_distances() -> None:
    cells = np.array([[0.0, 0.0], [250.0, 0.0], [300.0, 400.0]])  # distances 0, 250, 500
    p = centre_probability(cells, (0.0, 0.0), 0.012 * np.sqrt(2 * np.pi) * 250.0, 250.0)
    # 0.012 * exp(0) = 0.012; 0.012 * exp(-250^2 / (2 250^2)) = 0.012 * 0.60653066 = 0.0072783679;
    # 0.012 * exp(-500^2 / (2 250^2)) = 0.012 * exp(-2) = 0.012 * 0.13533528 = 0.0016240234
    assert p == pytest.approx([0.012, 0.0072783679, 0.0016240234], rel=1e-7)


def test_raw_gain_form_of_eq1() -> None:
    # K = 1, sigma = 1, at the centre: 1 / sqrt(2 pi) = 0.39894228
    assert centre_probability(np.zeros((1, 2)), (0.0, 0.0), 1.0, 1.0)[0] == pytest.approx(0.39894228)


def test_combination_is_one_minus_product_of_misses() -> None:
    # Centres A = (0, 0) peak 0.5 and B = (300, 400) peak 0.2, sigma 500; |AB| = 500, exp(-0.5) = 0.60653066.
    # Cell at A: pA = 0.5, pB = 0.2 * 0.60653066 = 0.12130613 -> 1 - 0.5 * 0.87869387 = 0.56065307
    # Cell at B: pA = 0.5 * 0.60653066 = 0.30326533, pB = 0.2 -> 1 - 0.69673467 * 0.8 = 0.44261226
    cells = np.array([[0.0, 0.0], [300.0, 400.0]])
    pr = prior_map(cells, [(0.0, 0.0, 0.5), (300.0, 400.0, 0.2)], 500.0)
    assert pr == pytest.approx([0.56065307, 0.44261226], rel=1e-7)


def test_two_identical_centres() -> None:
    # 1 - (1 - 0.5)^2 = 0.75, not the sum 1.0
    assert prior_map(np.zeros((1, 2)), [(0, 0, 0.5), (0, 0, 0.5)], 100.0)[0] == pytest.approx(0.75)


@settings(max_examples=50, deadline=None)
@given(
    st.lists(
        st.tuples(st.floats(-1000, 1000), st.floats(-1000, 1000), st.floats(0.001, 1.0)),
        min_size=1,
        max_size=5,
    ),
    st.floats(10.0, 1000.0),
)
def test_prior_is_a_probability_at_least_each_term(centres: list, sigma: float) -> None:
    cells = np.stack(np.meshgrid(np.linspace(-1000, 1000, 9), np.linspace(-1000, 1000, 9)), -1).reshape(-1, 2)
    pr = prior_map(cells, centres, sigma)
    assert np.all((pr >= 0) & (pr <= 1))
    for x, y, peak in centres:
        term = centre_probability(cells, (x, y), gain_for_peak(peak, sigma), sigma)
        assert np.all(pr >= term - 1e-12)


def test_draw_targets() -> None:
    prior = np.array([0.0, 0.5, 0.0, 0.1, 0.2, 0.0, 0.3])
    a = draw_targets(prior, 3, np.random.default_rng(5))
    b = draw_targets(prior, 3, np.random.default_rng(5))
    assert np.array_equal(a, b)
    assert len(set(a.tolist())) == 3 and np.all(np.diff(a) > 0)  # distinct and sorted
    assert np.all(prior[a] > 0)
    # only 4 cells can hold a target: at most one per cell
    assert sorted(draw_targets(prior, 9, np.random.default_rng(1)).tolist()) == [1, 3, 4, 6]
