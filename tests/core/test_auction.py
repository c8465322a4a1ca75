"""Algorithm 2: the local auction, with removal of allocated tasks."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from companion.core.auction import claim_priority, local_auction


def auction(bidders: list[int], bids: list[list[float]], available: list[bool] | None = None) -> dict:
    b = np.array(bids, dtype=float)
    av = np.ones(b.shape[1], dtype=bool) if available is None else np.array(available)
    return local_auction(bidders, b, av)


def test_each_bidder_gets_its_best_when_no_conflict() -> None:
    assert auction([0, 1], [[5.0, 3.0], [4.0, 6.0]]) == {0: (0, 5.0), 1: (1, 6.0)}


def test_highest_reward_wins_and_loser_takes_next() -> None:
    # task 0: UAV 1 bids 6 > 5 and wins; UAV 0 then gets task 1 (its only positive task left)
    assert auction([0, 1], [[5.0, 1.0], [6.0, 2.0]]) == {0: (1, 1.0), 1: (0, 6.0)}


def test_a_winner_of_several_keeps_the_best() -> None:
    # UAV 0 wins both tasks (10 > 8, 9 > 1), keeps task 0 (10); task 1 is re-auctioned to UAV 1
    assert auction([0, 1], [[10.0, 9.0], [8.0, 1.0]]) == {0: (0, 10.0), 1: (1, 1.0)}


def test_ties_go_to_the_lower_id_whatever_the_row_order() -> None:
    assert auction([0, 1], [[5.0, 1.0], [5.0, 1.0]]) == {0: (0, 5.0), 1: (1, 1.0)}
    assert auction([3, 1], [[5.0, 1.0], [5.0, 1.0]]) == {1: (0, 5.0), 3: (1, 1.0)}


def test_unavailable_tasks_are_never_assigned() -> None:
    # task 0 is held outside the auction: both want task 1, UAV 1 wins it, UAV 0 is left out
    assert auction([0, 1], [[9.0, 2.0], [9.0, 3.0]], [False, True]) == {1: (1, 3.0)}


def test_zero_rewards_are_never_assigned() -> None:
    assert auction([0, 1], [[0.0, 2.0], [0.0, 0.0]]) == {0: (1, 2.0)}
    assert auction([0], [[0.0, 0.0]]) == {}


def test_claim_priority() -> None:
    assert claim_priority(2.0, 5) > claim_priority(1.0, 0)  # higher reward first
    assert claim_priority(1.0, 0) > claim_priority(1.0, 3)  # then lower id


@st.composite
def auctions(draw: st.DrawFn) -> tuple[list[int], np.ndarray, np.ndarray]:
    n = draw(st.integers(1, 6))
    m = draw(st.integers(1, 8))
    ids = draw(st.lists(st.integers(0, 20), min_size=n, max_size=n, unique=True))
    vals = st.one_of(st.just(0.0), st.sampled_from([1.0, 2.0]), st.floats(0.0, 10.0))
    bids = draw(arrays(np.float64, (n, m), elements=vals))
    available = draw(arrays(np.bool_, m))
    return ids, bids, available


@settings(max_examples=50, deadline=None)
@given(auctions())
def test_auction_properties(case: tuple) -> None:
    ids, bids, available = case
    result = local_auction(ids, bids.copy(), available.copy())
    row = {u: i for i, u in enumerate(ids)}
    tasks = [j for j, _ in result.values()]
    assert set(result) <= set(ids)
    assert len(tasks) == len(set(tasks))  # one UAV per task
    for u, (j, r) in result.items():
        assert available[j] and bids[row[u], j] > 0 and r == bids[row[u], j]
    # a bidder is left out only when every positive available task went to someone else
    for u in set(ids) - set(result):
        wanted = {j for j in range(bids.shape[1]) if available[j] and bids[row[u], j] > 0}
        assert wanted <= set(tasks)
    # the overall highest bid wins its task (ties: lowest id, then lowest task)
    valid = np.where(available[None, :] & (bids > 0), bids, -np.inf)
    if np.isfinite(valid).any():
        best = valid.max()
        u_best = min(u for u in ids if np.any(valid[row[u]] == best))
        assert result[u_best][1] == best


def reference_auction(ids: list[int], bids: np.ndarray, available: np.ndarray) -> dict:
    """Algorithm 2 written out plainly: every round, each task goes to the open bidder with the
    highest positive reward (the lowest id among equals); each winner keeps its best task (the
    lowest task among equals); winners and their tasks leave; repeat until nothing is won."""
    open_ids, free, result = set(ids), {j for j in range(bids.shape[1]) if available[j]}, {}
    row = {u: i for i, u in enumerate(ids)}
    while True:
        won: dict[int, list[int]] = {}
        for j in sorted(free):
            offers = [(bids[row[u], j], -u) for u in open_ids if bids[row[u], j] > 0]
            if offers:
                won.setdefault(-max(offers)[1], []).append(j)
        if not won:
            return result
        for u, tasks in won.items():
            j = max(tasks, key=lambda t: (bids[row[u], t], -t))
            result[u] = (j, float(bids[row[u], j]))
            open_ids.discard(u)
            free.discard(j)


@settings(max_examples=200, deadline=None)
@given(auctions())
def test_auction_matches_algorithm_2_written_out(case: tuple) -> None:
    ids, bids, available = case
    assert local_auction(ids, bids.copy(), available.copy()) == reference_auction(ids, bids, available)
