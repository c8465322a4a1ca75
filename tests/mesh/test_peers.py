"""Real Zenoh sessions in one process, on 127.0.0.1: delivery, gating, loss, hostile input, liveliness."""

from __future__ import annotations

import math
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager

import msgspec
import numpy as np
import pytest
import zenoh
from mesh_helpers import N_CELLS, make_mission, outbox, until

from companion.batch.engine import Radio
from companion.contracts.mission import Mission
from companion.contracts.zenoh_config import peer_config
from companion.core.messages import PROTOCOL_VERSION, ClaimsMsg, CoverageMsg, Message, UavState
from companion.node.mesh import Bundle, Mesh, encode_bundle, key_base

pytestmark = pytest.mark.timeout(60)
OpenMesh = Callable[..., Mesh]


def _connect(meshes: list[Mesh]) -> None:
    ids = {m.uav for m in meshes}
    for m in meshes:
        assert m.wait_alive(ids - {m.uav}, 15.0) == set()


def test_two_peers_exchange_bundles(open_mesh: OpenMesh) -> None:
    mission = make_mission()
    a, b = open_mesh(mission, 0), open_mesh(mission, 1)
    _connect([a, b])
    a.publish(0, outbox(0, 0, 1.0, 2.0))
    b.publish(0, outbox(1, 0, 3.0, 4.0))
    assert a.wait_for(0, {1}, 10.0) == set()
    assert b.wait_for(0, {0}, 10.0) == set()
    assert a.inbox(1, (1.0, 2.0)) == outbox(1, 0, 3.0, 4.0)
    assert b.inbox(1, (3.0, 4.0)) == outbox(0, 0, 1.0, 2.0)
    assert a.stats.received == b.stats.received == 1
    assert a.inbox(2, (1.0, 2.0)) == []


def test_four_peers_gate_at_exactly_r_c_like_the_engine_radio(open_mesh: OpenMesh) -> None:
    mission = make_mission()
    r_c = mission.comms.range
    assert r_c == 1000.0
    # From UAV 0: UAV 1 and UAV 3 at exactly R_c, UAV 2 one ulp beyond.
    positions = np.array([[0.0, 0.0], [r_c, 0.0], [0.0, math.nextafter(r_c, math.inf)], [-600.0, 800.0]])
    meshes = [open_mesh(mission, i) for i in range(4)]
    _connect(meshes)
    radio = Radio(r_c, 0.0, np.random.default_rng(0), wire=True)
    for step in range(3):
        outboxes = [outbox(i, step, *map(float, positions[i])) for i in range(4)]
        for m in meshes:
            m.publish(step, outboxes[m.uav])
        expected = radio.deliver(positions, outboxes)
        for m in meshes:
            assert m.wait_for(step, {0, 1, 2, 3} - {m.uav}, 10.0) == set()
            assert m.inbox(step + 1, positions[m.uav]) == expected[m.uav]
    assert [msg.sender for msg in meshes[0].inbox(3, positions[0])] == []  # all taken already
    assert meshes[0].stats.out_of_range == 3 * 3  # UAV 2's three messages, three steps
    assert [msg.sender for msg in expected[0]] == [1, 1, 1, 3, 3, 3]


def test_loss_is_per_message_from_the_seeded_generator(open_mesh: OpenMesh) -> None:
    mission = make_mission(loss=0.3)
    a = open_mesh(mission, 0, rng=np.random.default_rng(1))
    b = open_mesh(mission, 1, rng=np.random.default_rng(5))
    _connect([a, b])
    reference = np.random.default_rng(5)
    kept = dropped = 0
    for step in range(60):
        msgs = [CoverageMsg(sender=0, stamp=step, x=0.0, y=0.0, cells=(j,)) for j in range(30)]
        a.publish(step, msgs)
        assert b.wait_for(step, {0}, 10.0) == set()
        expected = [m for m in msgs if reference.random() >= 0.3]
        assert b.inbox(step + 1, (5.0, 5.0)) == expected
        kept, dropped = kept + len(expected), dropped + len(msgs) - len(expected)
    assert b.stats.lost == dropped
    assert abs(dropped - 0.3 * 1800) < 5 * math.sqrt(1800 * 0.3 * 0.7)


def test_wait_for_returns_on_arrival_and_reports_missing_peers(open_mesh: OpenMesh) -> None:
    mission = make_mission()
    a, b, c = (open_mesh(mission, i) for i in range(3))
    _connect([a, b, c])
    timer = threading.Timer(0.2, lambda: b.publish(0, outbox(1, 0, 0.0, 0.0)))
    timer.start()
    try:
        assert a.wait_for(0, {1}, 20.0) == set()
    finally:
        timer.join()
    assert a.wait_for(0, {1, 2}, 0.3) == {2}
    c.publish(0, [], position=(0.0, 0.0))  # an empty outbox still counts for lockstep
    assert a.wait_for(0, {1, 2}, 10.0) == set()
    assert [m.sender for m in a.inbox(1, (0.0, 0.0))] == [1, 1, 1]


def test_stale_and_duplicate_bundles_are_counted(open_mesh: OpenMesh) -> None:
    mission = make_mission()
    a, b = open_mesh(mission, 0), open_mesh(mission, 1)
    _connect([a, b])
    for step in (0, 1):
        b.publish(step, outbox(1, step, 0.0, 0.0))
    assert a.wait_for(1, {1}, 10.0) == set()
    assert a.inbox(2, (0.0, 0.0)) == outbox(1, 1, 0.0, 0.0)
    assert a.stats.stale == 1  # stamp 0 was for step 1
    b.publish(1, outbox(1, 1, 0.0, 0.0))  # arrives after its step
    b.publish(3, outbox(1, 3, 0.0, 0.0))
    b.publish(3, outbox(1, 3, 0.0, 0.0))
    assert until(lambda: a.stats.duplicates == 1)
    assert a.stats.stale == 2
    assert a.inbox(4, (0.0, 0.0)) == outbox(1, 3, 0.0, 0.0)


@contextmanager
def _raw_session(mission: Mission, uav: int) -> Iterator[zenoh.Session]:
    """A bare peer posing as `uav`, returned once it sees UAV 0's token (hence its subscriber)."""
    seen = threading.Event()
    base = key_base(mission)
    with zenoh.open(peer_config(("tcp/127.0.0.1:0",), (mission.mesh.seed_endpoint,))) as session:
        session.liveliness().declare_subscriber(f"{base}/alive/0", lambda _s: seen.set(), history=True)
        token = session.liveliness().declare_token(f"{base}/alive/{uav}")
        assert seen.wait(15.0)
        yield session
        token.undeclare()


def test_malformed_and_hostile_payloads_are_dropped_and_counted(open_mesh: OpenMesh) -> None:
    mission = make_mission(max_bundle_bytes=4096)
    a = open_mesh(mission, 0)
    base = key_base(mission)

    def bundle(sender: int = 1, **changes: object) -> bytes:
        msgs = tuple(outbox(sender, 0, 0.0, 0.0))
        b = Bundle(sender=sender, stamp=0, x=0.0, y=0.0, messages=msgs)
        return encode_bundle(msgspec.structs.replace(b, **changes))

    def msg(**fields: object) -> Message:
        return CoverageMsg(sender=1, stamp=0, x=0.0, y=0.0, cells=(), **fields)

    too_many = tuple(UavState(uav=1, stamp=0, x=0.0, y=0.0, heading=0.0, plan=()) for _ in range(5))
    hostile = [
        ("uav/1/msg", b"garbage"),
        ("uav/1/msg", b""),
        ("uav/1/msg", bundle(v=PROTOCOL_VERSION + 1)),
        ("uav/1/msg", b"\x91" + b"\x00" * 4096),  # over max_bundle_bytes
        ("uav/9/msg", bundle(sender=9)),  # no such UAV
        ("uav/1/msg", bundle(x=math.nan)),
        ("uav/1/msg", bundle(messages=(msg(detections=(N_CELLS,)),))),  # cell index out of range
        ("uav/1/msg", bundle(messages=(ClaimsMsg(sender=1, stamp=0, x=0.0, y=0.0, known=too_many),))),
        ("uav/1/msg", bundle(messages=(msg(),), stamp=1)),  # message stamp differs from the bundle's
    ]
    spoofed = [
        ("uav/1/msg", bundle(sender=2)),  # sender differs from the key
        ("uav/0/msg", bundle(sender=0)),  # claims the receiver's id
        ("uav/x/msg", bundle()),
    ]
    with _raw_session(mission, 1) as raw:
        for key, payload in hostile + spoofed:
            raw.put(f"{base}/{key}", payload)
        raw.delete(f"{base}/uav/1/msg")
        raw.put(f"{base}/uav/1/msg", bundle())
        assert a.wait_for(0, {1}, 10.0) == set()
        assert until(lambda: a.stats.malformed == len(hostile) + 1)
        assert until(lambda: a.stats.spoofed == len(spoofed))
    assert a.inbox(1, (0.0, 0.0)) == outbox(1, 0, 0.0, 0.0)
    assert a.stats.received == 1


def test_peers_in_any_order_find_each_other_after_the_seed_leaves(open_mesh: OpenMesh) -> None:
    mission = make_mission()
    b = open_mesh(mission, 1)  # claims the seed endpoint
    c = open_mesh(mission, 2)  # joins through it
    _connect([b, c])
    b.close()
    assert until(lambda: c.alive_peers() == set())
    d = open_mesh(mission, 3)  # claims the freed seed endpoint; c reconnects to it
    _connect([c, d])
    d.publish(0, outbox(3, 0, 0.0, 0.0))
    assert c.wait_for(0, {3}, 10.0) == set()
    assert c.inbox(1, (0.0, 0.0)) == outbox(3, 0, 0.0, 0.0)
