"""The search's progress as one UAV reports it (`core.progress`)."""

from __future__ import annotations

import math

import numpy as np

from companion.core.progress import search_progress


def test_progress_from_the_prior_and_the_unseen_cells() -> None:
    seen = np.array([True, False, False, True])
    eta = np.array([0.25, 1.0, 1.0, 0.5])
    prior = np.array([0.9, 0.5, 0.2, 0.1])
    p = search_progress(seen, eta, prior, found={0})
    assert (p.coverage, p.mean_eta, p.found) == (0.5, 0.6875, 1)
    assert math.isclose(p.p_unfound, 1 - 0.5 * 0.8)  # the two unseen cells only


def test_found_cells_leave_nothing_behind() -> None:
    prior = np.array([0.3, 0.7])
    nothing_seen = search_progress(np.zeros(2, bool), np.ones(2), prior, found=set())
    assert math.isclose(nothing_seen.p_unfound, 1 - 0.7 * 0.3)
    assert search_progress(np.zeros(2, bool), np.ones(2), prior, found={0, 1}).p_unfound == 0.0
    assert search_progress(np.ones(2, bool), np.ones(2), prior, found=set()).p_unfound == 0.0
