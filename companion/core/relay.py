"""Multi-hop relaying: which peers' latest states a UAV passes on in its ClaimsMsg."""

from __future__ import annotations

from collections.abc import Iterable
from functools import reduce
from operator import or_

RELAY_MEMO_SIZE = 1024


def relay_set(
    me: int, own_heard: tuple[int, ...], neighbours: dict[int, tuple[int, ...]], peers: Iterable[int]
) -> tuple[int, ...]:
    """The peers whose latest state UAV `me` relays, ascending.

    Every UAV reports whom it heard first-hand at its previous step (`StateMsg.heard`); `me` knows
    the reports of the UAVs it heard this step (`neighbours`) and its own (`own_heard`). A peer p
    is relayed for a UAV l that `me` heard when l did not hear p itself, unless a UAV that l heard
    and that heard p (per the reports `me` knows) has a lower id than `me`: the lowest such UAV
    relays p to l. The true lowest one sees itself as lowest in its own view, so no pair is left
    out where the reports hold; where l is farther than two hops from p, everyone that has p
    relays. A swarm in which everyone hears everyone relays nothing.
    """
    reports = {**neighbours, me: own_heard}
    heard_by: dict[int, int] = {}  # p -> mask of the UAVs reported to have heard p
    for m, heard in reports.items():
        for p in heard:
            heard_by[p] = heard_by.get(p, 0) | 1 << m
    bit = 1 << me
    need: set[int] = set()
    for u, heard in neighbours.items():
        heard_u = reduce(or_, (1 << v for v in heard), 0)
        for p in peers:
            if p == u or p in need or heard_u >> p & 1:
                continue
            relayers = heard_u & heard_by.get(p, 0)
            if not relayers or relayers & -relayers == bit:
                need.add(p)
    return tuple(sorted(need))
