"""The liveliness bookkeeping of a companion (`companion.node.departures`): a peer whose token
vanished is forgotten at every step until its token is back, or until a state of it flown under
guidance and stamped after it left reaches this companion through the others."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from companion.core.messages import UavState
from companion.node.departures import Departures, DepartureUpdate


def state(uav: int, stamp: int, steered: bool = True) -> UavState:
    return UavState(uav=uav, stamp=stamp, x=0.0, y=0.0, heading=0.0, plan=(), steered=steered)


def test_a_peer_that_leaves_is_forgotten_every_step_while_only_stale_relays_arrive() -> None:
    d = Departures()
    assert d.update(0, {1, 2}, {}).forget == ()
    first = d.update(5, {2}, {1: state(1, 4)})
    assert (first.left, first.back, first.forget) == ((1,), (), (1,))
    later = d.update(6, {2}, {1: state(1, 4)})  # the others relay its last state: still gone
    assert (later.left, later.back, later.forget) == ((), (), (1,))
    assert d.update(7, {2}, {}).forget == (1,)


def test_a_restarted_peer_heard_only_through_the_others_is_back() -> None:
    d = Departures()
    d.update(0, {1, 2}, {})
    d.update(5, {2}, {1: state(1, 4)})
    back = d.update(14, {2}, {1: state(1, 13)})  # relayed: no link to the restarted companion
    assert (back.left, back.back, back.forget) == ((), (1,), ())
    assert d.update(15, {2}, {1: state(1, 14)}) == DepartureUpdate()  # told once, kept
    # it goes again (its state grows old, the agent's timeout drops it): forgotten again
    assert d.update(16, {2}, {}).forget == (1,)


def test_a_peer_that_cannot_steer_stays_gone_whatever_it_sends() -> None:
    d = Departures()
    d.update(0, {1}, {})
    d.update(3, set(), {})
    assert d.update(4, set(), {1: state(1, 4, steered=False)}).forget == (1,)


def test_a_token_that_comes_back_ends_the_departure() -> None:
    d = Departures()
    d.update(0, {1}, {})
    d.update(3, set(), {})
    assert d.update(9, {1}, {1: state(1, 2)}) == DepartureUpdate()  # back with its token
    assert d.left_at == {} and d.heard_back == set()
    again = d.update(11, set(), {1: state(1, 10)})  # a second departure, from step 11 on
    assert (again.left, again.forget) == ((1,), (1,))


@given(
    alive=st.lists(st.sets(st.integers(0, 5)), min_size=1, max_size=12),
    stamps=st.lists(st.integers(-1, 12), min_size=6, max_size=6),
)
def test_only_peers_seen_alive_and_now_without_a_token_are_forgotten(
    alive: list[set[int]], stamps: list[int]
) -> None:
    d, seen = Departures(), set()
    for k, now in enumerate(alive):
        known = {u: state(u, s) for u, s in enumerate(stamps) if s >= 0}
        change = d.update(k, now, known)
        seen |= now
        assert set(change.forget) == seen - now - d.heard_back
        assert set(change.back) <= d.heard_back <= seen - now
        for u in d.heard_back:  # kept only on a state stamped after it left
            assert known[u].stamp > d.left_at[u]
