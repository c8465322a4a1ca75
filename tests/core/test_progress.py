"""The search's progress as one UAV reports it (`core.progress`)."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.core.belief import Belief
from companion.core.progress import search_progress

CENTRES = np.array([[0.0, 0.0], [10.0, 0.0], [20.0, 0.0], [30.0, 0.0]])


def _looked(prior: np.ndarray, sensor: tuple[float, float, float, float], cells: list[int]) -> Belief:
    """A one-UAV map after misses at `cells` from straight above each."""
    b = Belief(prior, 1, 0, 0.999, 0.01)
    for step, c in enumerate(cells):
        at = (float(CENTRES[c, 0]), float(CENTRES[c, 1]))
        b.look(step, np.array([c]), np.zeros(1, dtype=np.bool_), at, CENTRES, sensor)
    return b


def test_progress_from_the_posterior_of_the_cells_not_confirmed() -> None:
    seen = np.array([True, False, False, True])
    eta = np.array([0.25, 1.0, 1.0, 0.5])
    posterior = np.array([0.9, 0.5, 0.2, 0.0])
    p = search_progress(seen, eta, posterior, found={0})
    assert (p.coverage, p.mean_eta, p.found) == (0.5, 0.6875, 1)
    assert math.isclose(p.p_unfound, 1 - 0.5 * 0.8)  # cell 0 confirmed, cell 3 cleared


def test_confirmed_cells_leave_nothing_behind() -> None:
    posterior = np.array([0.3, 0.7])
    nothing_seen = search_progress(np.zeros(2, bool), np.ones(2), posterior, found=set())
    assert math.isclose(nothing_seen.p_unfound, 1 - 0.7 * 0.3)
    assert search_progress(np.zeros(2, bool), np.ones(2), posterior, found={0, 1}).p_unfound == 0.0


@settings(max_examples=60, deadline=None)
@given(
    prior=st.lists(st.floats(0.0, 0.95), min_size=4, max_size=4),
    cells=st.lists(st.integers(0, 3), max_size=6),
)
def test_a_perfect_sensor_leaves_the_prior_of_the_unseen_cells(prior: list[float], cells: list[int]) -> None:
    """Pd = 1, Pf = 0: a miss clears its cell, so P(left) is the prior's mass never looked at."""
    b = _looked(np.array(prior), (1.0, 1.0, 0.0, 60.0), cells)
    seen = np.isin(np.arange(4), cells)
    p = search_progress(seen, np.ones(4), b.posterior(), found=set())
    unseen = np.prod([1 - prior[c] for c in range(4) if c not in cells])
    assert math.isclose(p.p_unfound, 1 - unseen, abs_tol=1e-5)


@settings(max_examples=60, deadline=None)
@given(prior=st.floats(0.05, 0.95), looks=st.integers(1, 5))
def test_a_detector_that_misses_leaves_some_chance_in_a_cell_it_saw(prior: float, looks: int) -> None:
    """Pd = 0.7: each miss divides the odds by 1 / 0.3, no more; Bayes' rule for one cell."""
    b = _looked(np.array([prior, 0.0, 0.0, 0.0]), (0.7, 0.7, 0.0, 60.0), [0] * looks)
    p = search_progress(np.ones(4, bool), np.ones(4), b.posterior(), found=set()).p_unfound
    odds = prior / (1 - prior) * 0.3**looks
    assert math.isclose(p, odds / (1 + odds), rel_tol=1e-4)
    assert 0.0 < p < prior
