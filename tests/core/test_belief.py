"""The target-probability map (`core.belief`): Bayes' rule per look, exact fusion of evidence records.

The property the fusion must have: whatever order the records travel in, through whatever relays,
with duplicates, the fused posterior equals that of one UAV that made every look itself.
"""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.core.belief import Belief
from companion.core.sensing import LLR_CAP, look_llr

N_CELLS = 12
CENTRES = np.stack([np.arange(N_CELLS) * 40.0, np.zeros(N_CELLS)], axis=1)
PRIOR = np.linspace(0.001, 0.3, N_CELLS)
MODEL = (0.9, 0.6, 0.02, 60.0)  # pd, pd_edge, pf, R_A

looks = st.lists(
    st.tuples(
        st.integers(0, 1),  # which UAV looks
        st.integers(0, N_CELLS - 1),  # at which cell
        st.booleans(),  # hit or miss
        st.floats(0.0, 60.0),  # from how far
    ),
    max_size=40,
)


def _fly(belief: Belief, step: int, cell: int, hit: bool, distance: float) -> None:
    """One look at `cell` from `distance` metres along the row."""
    at = (float(CENTRES[cell, 0]) - distance, 0.0)
    belief.look(step, np.array([cell]), np.array([hit]), at, CENTRES, MODEL)


def _records(b: Belief) -> tuple[np.ndarray, np.ndarray]:
    """Every record `b` holds (not only those at the cells of interest)."""
    sources, cells = np.nonzero(b.stamps >= 0)
    return np.stack([sources, cells, b.stamps[sources, cells]], axis=1), b.evidence[sources, cells]


@settings(max_examples=200, deadline=None)
@given(looks, st.randoms(use_true_random=False), st.booleans())
def test_fused_posterior_equals_one_uav_making_every_look(made, rnd, via_relay: bool) -> None:
    uavs = [Belief(PRIOR, 3, me, 0.999, 0.01) for me in range(2)]
    alone = Belief(PRIOR, 3, 0, 0.999, 0.01)
    for step, (uav, cell, hit, distance) in enumerate(made):
        _fly(uavs[uav], step, cell, hit, distance)
        _fly(alone, step, cell, hit, distance)
    # exchange: each UAV's records reach the other, directly or through a relay (UAV 2, which
    # looks at nothing), split into pieces, shuffled and some sent twice
    relay = Belief(PRIOR, 3, 2, 0.999, 0.01)
    pieces = []
    for sender in (0, 1):
        triples, values = _records(uavs[sender])
        for i in range(values.shape[0]):
            pieces.append((1 - sender, triples[i : i + 1], values[i : i + 1]))
    pieces += rnd.sample(pieces, len(pieces) // 2)  # duplicates
    rnd.shuffle(pieces)
    for to, triples, values in pieces:
        if via_relay:
            relay.merge(triples, values)
            triples, values = _records(relay)
        uavs[to].merge(triples, values)
    for b in uavs:
        assert np.array_equal(b.logodds, alone.logodds)  # exact, not approximately


@given(looks)
@settings(max_examples=100, deadline=None)
def test_posterior_is_bayes_rule_over_the_looks(made) -> None:
    b = Belief(PRIOR, 2, 0, 0.999, 0.01)
    target, empty = np.ones(N_CELLS), np.ones(N_CELLS)  # P(reports | target), P(reports | empty)
    pd, pd_edge, pf, radius = MODEL
    for step, (_, cell, hit, distance) in enumerate(made):
        _fly(b, step, cell, hit, distance)
        p = pd + (pd_edge - pd) * distance / radius
        target[cell] *= p if hit else 1 - p
        empty[cell] *= pf if hit else 1 - pf
    expected = PRIOR * target / (PRIOR * target + (1 - PRIOR) * empty)
    assert np.allclose(b.posterior(), expected, rtol=1e-5, atol=1e-12)


def test_a_perfect_sensor_confirms_on_the_first_hit_and_clears_on_a_miss() -> None:
    assert look_llr(True, 10.0, 1.0, 1.0, 0.0, 60.0) == LLR_CAP
    assert look_llr(False, 10.0, 1.0, 1.0, 0.0, 60.0) == -LLR_CAP
    b = Belief(PRIOR, 1, 0, 0.999, 0.01)
    cells = np.array([2, 5])
    b.look(0, cells, np.array([True, False]), (80.0, 0.0), CENTRES, (1.0, 1.0, 0.0, 60.0))
    assert b.confirmed().tolist() == [2] and b.candidates().size == 0
    assert b.posterior(np.array([5]))[0] < 1e-15


def test_one_hit_makes_a_candidate_and_a_second_look_decides_it() -> None:
    b = Belief(PRIOR, 2, 0, 0.999, 0.01)
    cell = 4
    _fly(b, 0, cell, True, 0.0)  # one hit at Pd 0.9, Pf 0.02 from a prior of about 0.1
    assert b.candidates().tolist() == [cell] and b.confirmed().size == 0
    _fly(b, 1, cell, True, 0.0)
    _fly(b, 2, cell, True, 0.0)
    assert b.confirmed().tolist() == [cell] and b.candidates().size == 0
    c = Belief(PRIOR, 2, 0, 0.999, 0.01)
    _fly(c, 0, cell, True, 0.0)
    _fly(c, 1, cell, False, 0.0)
    _fly(c, 2, cell, False, 0.0)
    assert c.candidates().size == 0 and c.posterior(np.array([cell]))[0] < PRIOR[cell]  # cleared


def test_relayed_records_are_the_cells_of_interest_and_merging_twice_changes_nothing() -> None:
    a, b = Belief(PRIOR, 2, 0, 0.999, 0.01), Belief(PRIOR, 2, 1, 0.999, 0.01)
    _fly(a, 0, 3, True, 0.0)
    _fly(a, 1, 7, False, 0.0)
    flat, values = (np.array(x) for x in a.records())
    triples = flat.reshape(-1, 3)
    assert triples.tolist() == [[0, 3, 0]]  # the candidate only, not the miss
    b.merge(triples, values)
    once = b.logodds.copy()
    b.merge(triples, values)
    assert np.array_equal(once, b.logodds) and b.candidates().tolist() == [3]
    assert math.isclose(b.posterior(np.array([3]))[0], a.posterior(np.array([3]))[0])
    assert not b.merge(np.array([[1, 3, 5]]), np.array([1.0])).any()  # its own evidence: only it adds
