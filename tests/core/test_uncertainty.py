"""Eqs. 10-11 (eta <- gamma^h eta), eq. 12 (s = eta Pr) and eq. 30."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.core.uncertainty import apply_looks, global_average_uncertainty, importance, mark_seen


def test_repeated_looks_give_gamma_to_the_h() -> None:
    eta = np.array([1.0, 1.0, 1.0, 0.5])
    # cell 0 seen twice (0.1^2 = 0.01), cell 2 once (0.1), cell 3 once (0.5 * 0.1 = 0.05);
    # 4 (= len, the padding index) and -1 are ignored
    apply_looks(eta, np.array([0, 0, 2, 4, -1, 3], dtype=np.int64), 0.1)
    assert eta == pytest.approx([0.01, 1.0, 0.1, 0.05])


def test_cooperative_looks_multiply_in() -> None:
    # own look at cell 1 and two neighbours' looks at cell 1: h = 3 -> 0.5^3 = 0.125
    eta = np.ones(3)
    cells = np.concatenate([np.array([1]), np.array([1, 2]), np.array([1])]).astype(np.int64)
    apply_looks(eta, cells, 0.5)
    assert eta == pytest.approx([1.0, 0.125, 0.5])


def test_importance_and_global_average() -> None:
    # eq. 12: s = eta * Pr = [0.5 * 0.2, 1 * 0.1] = [0.1, 0.1]
    assert importance(np.array([0.5, 1.0]), np.array([0.2, 0.1])) == pytest.approx([0.1, 0.1])
    # eq. 30: mean over both UAVs and both cells: (1 + 0.5 + 0.1 + 0.2) / 4 = 0.45
    assert global_average_uncertainty(np.array([[1.0, 0.5], [0.1, 0.2]])) == pytest.approx(0.45)


def test_mark_seen_counts_first_looks_per_task() -> None:
    seen = np.zeros(4, dtype=bool)
    covered = np.zeros(2, dtype=np.int64)
    labels = np.array([0, 0, 1, 1], dtype=np.int64)
    mark_seen(seen, covered, labels, np.array([0, 0, 2, 4], dtype=np.int64))  # 4: padding
    assert seen.tolist() == [True, False, True, False] and covered.tolist() == [1, 1]
    mark_seen(seen, covered, labels, np.array([0, 1, 2], dtype=np.int64))  # only cell 1 is new
    assert covered.tolist() == [2, 1]


@settings(max_examples=50, deadline=None)
@given(
    st.integers(1, 30).flatmap(
        lambda n: st.tuples(
            st.just(n),
            st.lists(st.lists(st.integers(-2, n + 1), max_size=20), max_size=8),
        )
    ),
    st.floats(0.0, 0.999),
    st.floats(0.01, 1.0),
)
def test_eta_stays_in_unit_interval_and_never_rises(data: tuple, gamma: float, eta0: float) -> None:
    n, looks = data
    eta = np.full(n, eta0)
    h = np.zeros(n)
    for cells in looks:
        before = eta.copy()
        arr = np.array(cells, dtype=np.int64)
        apply_looks(eta, arr, gamma)
        assert np.all((eta >= 0.0) & (eta <= 1.0))
        assert np.all(eta <= before)
        valid = arr[(arr >= 0) & (arr < n)]
        h += np.bincount(valid, minlength=n)
    assert np.allclose(eta, eta0 * gamma**h, rtol=1e-9, atol=1e-300)
