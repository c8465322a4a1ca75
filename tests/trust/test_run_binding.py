"""Signatures bound to one run, and keys rotated without restarting the swarm: real Zenoh sessions
on 127.0.0.1, each member with its own certificate and signing key.

A compromised member (UAV 2's credentials) relays UAV 0's state as UAV 0 genuinely signed it in an
earlier run of the same mission: the receivers of the later run refuse it as forged and log it,
while the same relay of a state signed in the current run is taken. A bundle UAV 0 signed in an
earlier run, put again on its key (transport security off: signatures alone), is refused as
unauthenticated. A UAV whose signing key is rotated (`keys.rotate`) restarts alone; its peers take
its bundles under the new key without a restart.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterator
from contextlib import ExitStack
from pathlib import Path

import msgspec
import pytest

from companion.app.view.live import MeshListener
from companion.contracts import keys
from companion.contracts.mission import Mission
from companion.contracts.zenoh_config import MeshConfig, MeshSecurity
from companion.core.messages import ClaimsMsg, Message, StateMsg, UavState
from companion.core.world import build_world
from companion.node.mesh import Bundle, Mesh, encode_bundle, key_base, mission_authenticator
from companion.node.signing import Authenticator, decode_envelope
from tests.trust.test_secure_mesh import N_CELLS, N_TASKS, _mission, _outbox, _session, _until

pytestmark = pytest.mark.timeout(120)
EARLIER, LATER = "run-earlier", "run-later"


@pytest.fixture
def stack() -> Iterator[ExitStack]:
    with ExitStack() as s:
        yield s


def _auth(mission: Mission, uav: int) -> Authenticator:
    """UAV `uav`'s authenticator in the run $UAVSEARCH_RUN names (as its companion would build it)."""
    auth = mission_authenticator(mission, keys.for_mission(mission, keys.uav_identity(uav)))
    assert auth is not None
    return auth


def _state_signed_by_uav0(mission: Mission, step: int) -> tuple[UavState, bytes]:
    """UAV 0's state at `step` and its own signature of it (what travels with its bundle)."""
    auth = _auth(mission, 0)
    outbox = _outbox(0, step)
    bundle = Bundle(sender=0, stamp=step, x=0.0, y=0.0, messages=tuple(outbox))
    envelope = decode_envelope(auth.seal(encode_bundle(bundle), bundle.messages))
    state = outbox[0]
    assert isinstance(state, StateMsg)
    return state.state, envelope.state_sigs[0]


def _relay(rogue_auth: Authenticator, state: UavState, sig: bytes, step: int) -> bytes:
    """UAV 2's bundle at `step` relaying UAV 0's `state` with the signature `sig` (held as checked:
    a compromised member can hold any signature it ever saw)."""
    rogue_auth._keep(0, msgspec.msgpack.encode(state), (sig, True))
    head = {"sender": 2, "stamp": step, "x": 0.0, "y": 0.0}
    own = UavState(uav=2, stamp=step, x=0.0, y=0.0, heading=0.5, plan=())
    messages: list[Message] = [StateMsg(**head, state=own), ClaimsMsg(**head, known=(state,))]
    bundle = Bundle(sender=2, stamp=step, x=0.0, y=0.0, messages=tuple(messages))
    return rogue_auth.seal(encode_bundle(bundle), bundle.messages)


def test_a_state_signed_in_an_earlier_run_is_refused_and_logged(
    stack: ExitStack, key_dir: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    mission = _mission(key_dir)
    monkeypatch.setenv(keys.RUN_ENV, EARLIER)
    old_state, old_sig = _state_signed_by_uav0(mission, 3)
    monkeypatch.setenv(keys.RUN_ENV, LATER)
    receiver = stack.enter_context(
        Mesh(mission, 1, N_CELLS, N_TASKS, keys=keys.for_mission(mission, keys.uav_identity(1)))
    )
    view = MeshListener(build_world(mission, mission.seed, 0), keys.for_mission(mission, "view"))
    stack.callback(view.close)
    assert _until(lambda: view.status().connected, 30.0), view.status()
    rogue_keys = keys.for_mission(mission, keys.uav_identity(2))
    assert rogue_keys is not None and rogue_keys.run == LATER
    rogue = _session(stack, mission, MeshSecurity.of(rogue_keys, mission))
    assert _until(lambda: len(rogue.info.peers_zid()) == 2), "UAV 2's credentials join the mesh"
    time.sleep(1.0)  # the receiver's and the view's subscriptions reach the rogue
    rogue_auth = _auth(mission, 2)
    key = f"{key_base(mission)}/uav/2/msg"
    with caplog.at_level(logging.WARNING, logger="companion.mesh"):
        rogue.put(key, _relay(rogue_auth, old_state, old_sig, 10))
        assert _until(lambda: receiver.stats.forged == 1), receiver.stats
        # the same relay of a state UAV 0 signed in this run is taken: only the run differs
        new_state, new_sig = _state_signed_by_uav0(mission, 3)
        rogue.put(key, _relay(rogue_auth, new_state, new_sig, 11))
        assert _until(lambda: receiver.stats.received == 1), receiver.stats
    assert receiver.stats.forged == 1 and receiver.stats.unauthenticated == 0
    warnings = [
        r.getMessage()
        for r in caplog.records
        if r.name == "companion.mesh" and "refused forged bundle" in r.getMessage()
    ]
    assert len(warnings) == 1 and "uav/2" in warnings[0], warnings
    assert receiver.refusals.summary() == {"forged bundle": {"key uav/2": 1}}
    assert _until(lambda: view.status().received == 1), view.status()  # the live view shows it too
    assert view.status().refused == {"forged bundle": {"key uav/2": 1}}, view.status()


def test_a_bundle_signed_in_an_earlier_run_is_unauthenticated_in_a_later_one(
    stack: ExitStack, key_dir: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Transport security off (plain TCP), so that a bare session can put on UAV 0's key:
    signatures alone refuse its bundle of the earlier run, and take the same bundle of this one."""
    mission = _mission(key_dir)
    monkeypatch.setenv(keys.RUN_ENV, EARLIER)
    outbox = _outbox(0, 0)
    bundle = Bundle(sender=0, stamp=0, x=0.0, y=0.0, messages=tuple(outbox))
    earlier = _auth(mission, 0).seal(encode_bundle(bundle), bundle.messages)
    monkeypatch.setenv(keys.RUN_ENV, LATER)
    later = _auth(mission, 0).seal(encode_bundle(bundle), bundle.messages)
    plain = MeshConfig("peer", (mission.mesh.seed_endpoint,), ())
    receiver = stack.enter_context(
        Mesh(mission, 1, N_CELLS, N_TASKS, config=plain, keys=keys.for_mission(mission, "uav-1"))
    )
    rogue = _session(stack, mission, None)
    assert _until(lambda: len(rogue.info.peers_zid()) == 1)
    time.sleep(1.0)
    rogue.put(f"{key_base(mission)}/uav/0/msg", earlier)
    assert _until(lambda: receiver.stats.unauthenticated == 1), receiver.stats
    rogue.put(f"{key_base(mission)}/uav/0/msg", later)
    assert _until(lambda: receiver.stats.received == 1), receiver.stats
    assert receiver.stats.unauthenticated == 1


def test_a_rotated_key_is_taken_without_restarting_the_peers(
    stack: ExitStack, key_dir: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    mission = _mission(key_dir)
    monkeypatch.setenv(keys.RUN_ENV, LATER)
    peer = stack.enter_context(Mesh(mission, 0, N_CELLS, N_TASKS, keys=keys.for_mission(mission, "uav-0")))
    old = Mesh(mission, 1, N_CELLS, N_TASKS, keys=keys.for_mission(mission, "uav-1"))
    assert peer.wait_alive({1}, 30.0) == set()
    old.publish(0, _outbox(1, 0))
    assert peer.wait_for(0, {1}, 15.0) == set()
    old.close()  # UAV 1's companion stops...
    keys.rotate(key_dir, 1)  # ...gets a new signing key (its old one stays listed)...
    rotated = keys.for_mission(mission, "uav-1")
    assert rotated is not None and len(rotated.public[1]) == 2
    new = stack.enter_context(Mesh(mission, 1, N_CELLS, N_TASKS, keys=rotated))  # ...and starts again
    assert _until(lambda: peer.alive_peers() == {1}, 30.0)
    time.sleep(1.0)
    for step in (1, 2):
        new.publish(step, _outbox(1, step))
        assert peer.wait_for(step, {1}, 15.0) == set(), peer.stats
    s = peer.stats
    assert (s.received, s.unauthenticated, s.forged) == (3, 0, 0), s
