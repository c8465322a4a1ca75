"""Signed bundles and relayed states (`companion.node.signing`) with real Ed25519 keys.

A relay chain 0 -> 1 -> 2: UAV 1 relays UAV 0's state to UAV 2, which can check that UAV 0 said it;
a relay that alters the state, a bundle signed by the wrong UAV, one from another mission and an
unsigned one are all refused with their own error.
"""

from __future__ import annotations

from pathlib import Path

import msgspec
import pytest
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

from companion.contracts import keys
from companion.core.messages import ClaimsMsg, CoverageMsg, Message, StateMsg, UavState
from companion.node.signing import Authenticator, Forged, Unauthenticated, decode_envelope

BASE = "uavsearch/test"


def _auths(key_dir: Path, base: str = BASE) -> list[Authenticator]:
    loaded = [keys.load(key_dir, keys.uav_identity(i)) for i in range(4)]
    return [Authenticator(k.public, base, k.signing) for k in loaded]


def _state(uav: int, stamp: int, x: float = 10.0) -> UavState:
    return UavState(uav, stamp, x, -20.0, 0.5, ((x, 30.0),), task=uav)


def _outbox(uav: int, stamp: int, relayed: tuple[UavState, ...] = ()) -> list[Message]:
    head = {"sender": uav, "stamp": stamp, "x": 1.0, "y": 2.0}
    out: list[Message] = [StateMsg(**head, state=_state(uav, stamp)), CoverageMsg(**head, cells=(3,))]
    if relayed:
        out.append(ClaimsMsg(**head, known=relayed))
    return out


def _send(auth: Authenticator, messages: list[Message]) -> tuple[bytes, list[Message]]:
    """What a Mesh puts on the wire for `messages` (a stand-in body: the signatures cover bytes)."""
    messages = auth.relayable(messages)
    body = msgspec.msgpack.encode(messages)
    return auth.seal(body, messages), messages


def test_a_state_relayed_over_two_hops_still_proves_its_origin(key_dir: Path) -> None:
    a0, a1, a2 = _auths(key_dir)[:3]
    wire, msgs = _send(a0, _outbox(0, 5))
    a1.check(decode_envelope(wire), 0, msgs)  # UAV 1 hears UAV 0 first-hand...
    wire, msgs = _send(a1, _outbox(1, 6, relayed=(_state(0, 5),)))
    assert any(isinstance(m, ClaimsMsg) for m in msgs), "a state we hold a signature of is relayed"
    a2.check(decode_envelope(wire), 1, msgs)  # ...and UAV 2 checks UAV 0's own signature on it


def test_a_relay_cannot_alter_or_invent_a_state(key_dir: Path) -> None:
    a0, a1, a2 = _auths(key_dir)[:3]
    wire, msgs = _send(a0, _outbox(0, 5))
    a1.check(decode_envelope(wire), 0, msgs)
    wire, msgs = _send(a1, _outbox(1, 6, relayed=(_state(0, 5),)))
    env = decode_envelope(wire)
    moved = [*msgs[:2], ClaimsMsg(sender=1, stamp=6, x=1.0, y=2.0, known=(_state(0, 5, x=999.0),))]
    with pytest.raises(Forged):
        a2.check(env, 1, moved)  # the bundle signature is UAV 1's, but UAV 0 never said x = 999
    # a state UAV 1 never received signed is not relayed at all: it cannot sign for UAV 0
    _, msgs = _send(a1, _outbox(1, 7, relayed=(_state(0, 6),)))
    assert not any(isinstance(m, ClaimsMsg) for m in msgs)


def test_a_state_its_own_uav_signed_wrongly_is_believed_first_hand_but_never_relayed(key_dir: Path) -> None:
    a0, a1, a2 = _auths(key_dir)[:3]
    wire, msgs = _send(a0, _outbox(0, 5))
    env = decode_envelope(wire)
    bad = msgspec.structs.replace(env, state_sigs=(bytes(64),))
    a1.check(bad, 0, msgs)  # the bundle is UAV 0's: what it says about itself stands
    _, relayed = _send(a1, _outbox(1, 6, relayed=(_state(0, 5),)))
    assert not any(isinstance(m, ClaimsMsg) for m in relayed), "a bad signature is not passed on"
    a2.check(env, 0, msgs)  # the good one is, once checked
    _, relayed = _send(a2, _outbox(2, 6, relayed=(_state(0, 5),)))
    assert any(isinstance(m, ClaimsMsg) for m in relayed)


def test_bundles_signed_by_another_uav_another_mission_or_nobody_are_refused(key_dir: Path) -> None:
    a0, a1, a2 = _auths(key_dir)[:3]
    wire, msgs = _send(a1, _outbox(1, 3))
    with pytest.raises(Unauthenticated):
        a2.check(decode_envelope(wire), 0, msgs)  # UAV 1's bundle presented as UAV 0's
    other_mission = _auths(key_dir, base="uavsearch/other")[2]
    with pytest.raises(Unauthenticated):
        other_mission.check(decode_envelope(wire), 1, msgs)  # replayed into another mission
    stranger = Authenticator(a0.public, BASE, Ed25519PrivateKey.generate())
    wire, msgs = _send(stranger, _outbox(0, 3))
    with pytest.raises(Unauthenticated):
        a2.check(decode_envelope(wire), 0, msgs)  # a key the swarm does not list
    env = decode_envelope(_send(a0, _outbox(0, 4))[0])
    with pytest.raises(Forged):  # the state signatures are not optional
        a2.check(msgspec.structs.replace(env, state_sigs=()), 0, _outbox(0, 4))
    a2.check(env, 0, _outbox(0, 4))


def test_a_listener_without_a_key_checks_but_cannot_send(key_dir: Path) -> None:
    view = keys.load(key_dir, "view")
    listener = Authenticator(view.public, BASE)
    wire, msgs = _send(_auths(key_dir)[3], _outbox(3, 1))
    listener.check(decode_envelope(wire), 3, msgs)
    with pytest.raises(ValueError, match="cannot send"):
        listener.seal(b"", [])
