"""A secured mesh with real Zenoh sessions on 127.0.0.1: mutual TLS, access control, signatures.

Each layer is shown to stop an attacker on its own, with the receivers' counters: an outsider
cannot join (no certificate from the swarm's CA); a member cannot put on another UAV's key (access
control: what it puts on its own key right after is counted, what it put on the other's never
is); with transport security off, signatures alone count every forged bundle; the live view
joins with its own certificate and can only listen.
"""

from __future__ import annotations

import socket
import time
import uuid
from collections.abc import Callable, Iterator
from contextlib import ExitStack
from pathlib import Path

import msgspec
import pytest
import zenoh

from companion.app.view.live import MeshListener
from companion.contracts import keys
from companion.contracts.keys import TlsFiles
from companion.contracts.mission import Mission
from companion.contracts.zenoh_config import MeshConfig, MeshSecurity, peer_config
from companion.core.feasibility import load_mission
from companion.core.messages import CoverageMsg, Message, StateMsg, UavState
from companion.core.world import build_world
from companion.node.mesh import Bundle, Mesh, encode_bundle, key_base, mission_authenticator
from tests.trust.conftest import secured

pytestmark = pytest.mark.timeout(120)
ROOT = Path(__file__).resolve().parents[2]
N_CELLS, N_TASKS = 2500, 4
ATTEMPTS = 5
QUIET_S = 3.0  # how long an attacker that must get nowhere is given


def _free_endpoint() -> str:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


def _mission(key_dir: Path) -> Mission:
    base = load_mission(ROOT / "mission_files" / "scenario1.toml")
    mesh = msgspec.structs.replace(
        base.mesh, key_prefix=f"trust{uuid.uuid4().hex[:10]}", seed_endpoint=_free_endpoint()
    )
    return secured(msgspec.structs.replace(base, mesh=mesh), key_dir)


def _outbox(uav: int, step: int) -> list[Message]:
    head = {"sender": uav, "stamp": step, "x": 0.0, "y": 0.0}
    state = UavState(uav=uav, stamp=step, x=0.0, y=0.0, heading=0.5, plan=())
    return [StateMsg(**head, state=state), CoverageMsg(**head, cells=(uav,))]


def _bundle(sender: int, step: int) -> Bundle:
    return Bundle(sender=sender, stamp=step, x=0.0, y=0.0, messages=tuple(_outbox(sender, step)))


def _bare(sender: int, step: int = 0) -> bytes:
    """An unsigned bundle (an insecure mesh's wire form) naming `sender`."""
    return encode_bundle(_bundle(sender, step))


def _signed_by(key_dir: Path, mission: Mission, signer: int, sender: int, step: int) -> bytes:
    """A bundle naming `sender`, signed (bundle and state) with UAV `signer`'s key."""
    auth = mission_authenticator(mission, keys.load(key_dir, keys.uav_identity(signer)))
    assert auth is not None
    bundle = _bundle(sender, step)
    return auth.seal(encode_bundle(bundle), bundle.messages)


def _until(predicate: Callable[[], bool], timeout: float = 15.0) -> bool:
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.02)
    return True


@pytest.fixture
def stack() -> Iterator[ExitStack]:
    with ExitStack() as s:
        yield s


def _member(stack: ExitStack, mission: Mission, uav: int, config: MeshConfig | None = None) -> Mesh:
    k = keys.for_mission(mission, keys.uav_identity(uav))
    return stack.enter_context(Mesh(mission, uav, N_CELLS, N_TASKS, config=config, keys=k))


def _session(stack: ExitStack, mission: Mission, security: MeshSecurity | None) -> zenoh.Session:
    """A bare session that connects to the mission's seed endpoint (as `security`, or in plain TCP)."""
    session = zenoh.open(peer_config(("tcp/127.0.0.1:0",), (mission.mesh.seed_endpoint,), security))
    stack.callback(session.close)
    return session


def test_members_talk_and_outsiders_cannot_join(stack: ExitStack, key_dir: Path, tmp_path: Path) -> None:
    mission = _mission(key_dir)
    a, b = _member(stack, mission, 0), _member(stack, mission, 1)
    assert a.wait_alive({1}, 30.0) == set()
    other = tmp_path / "other-swarm"
    keys.generate(other, 4)  # a well-formed certificate for "uav-2", from a CA the swarm does not trust
    forged = keys.load(other, "uav-2").tls
    trusting = TlsFiles(key_dir / "ca.pem", forged.cert, forged.key)  # trusts the swarm's (public) CA
    outsiders = [
        _session(stack, mission, None),
        _session(stack, mission, MeshSecurity(trusting, key_base(mission), mission.n_uavs)),
    ]
    base = key_base(mission)
    for o in outsiders:
        token = o.liveliness().declare_token(f"{base}/alive/2")
        stack.callback(token.undeclare)
        for step in range(ATTEMPTS):
            o.put(f"{base}/uav/2/msg", _bare(2, step))
    time.sleep(QUIET_S)
    assert [o.info.peers_zid() for o in outsiders] == [[], []], "an outsider got a link"
    assert a.alive_peers() == {1} and b.alive_peers() == {0}, "an outsider's token was seen"
    b.publish(0, _outbox(1, 0))
    assert a.wait_for(0, {1}, 15.0) == set()
    s = a.stats
    assert (s.received, s.malformed, s.spoofed, s.unauthenticated, s.forged) == (1, 0, 0, 0, 0)


def test_access_control_keeps_a_member_to_its_own_keys(stack: ExitStack, key_dir: Path) -> None:
    """UAV 1's credentials and key, used by a second session (a compromised member), put bundles
    naming UAV 0: on UAV 0's key they are dropped by the receivers' access control (had they
    arrived, they would count as unauthenticated: UAV 1 signed them); on UAV 1's own key, put right
    after on the same link, they arrive and count as spoofed."""
    mission = _mission(key_dir)
    victim, witness = _member(stack, mission, 0), _member(stack, mission, 2)
    rogue = _session(stack, mission, MeshSecurity.of(keys.load(key_dir, "uav-1"), mission))
    assert witness.wait_alive({0}, 30.0) == set()
    base = key_base(mission)
    assert _until(lambda: len(rogue.info.peers_zid()) == 2), "a member's credentials join the mesh"
    time.sleep(1.0)  # the members' subscriptions reach the rogue
    for step in range(ATTEMPTS):
        rogue.put(f"{base}/uav/0/msg", _signed_by(key_dir, mission, 1, 0, step))  # denied: not its key
    for step in range(ATTEMPTS):
        rogue.put(f"{base}/uav/1/msg", _signed_by(key_dir, mission, 1, 0, step))  # its key, naming UAV 0
    for m in (victim, witness):
        assert _until(lambda m=m: m.stats.spoofed == ATTEMPTS), m.stats
        assert m.stats.unauthenticated == m.stats.received == m.stats.malformed == 0


def test_signatures_alone_reject_forged_bundles(stack: ExitStack, key_dir: Path) -> None:
    """Transport security off (plain TCP, no access control), signatures on: every bundle a bare
    session puts under UAV 0's key is counted unauthenticated, and UAV 0's real ones still arrive."""
    mission = _mission(key_dir)
    plain = MeshConfig("peer", (mission.mesh.seed_endpoint,), ())
    real = _member(stack, mission, 0, plain)
    joiner = MeshConfig("peer", ("tcp/127.0.0.1:0",), (mission.mesh.seed_endpoint,))
    receiver = _member(stack, mission, 2, joiner)
    assert receiver.wait_alive({0}, 30.0) == set()
    rogue = _session(stack, mission, None)
    assert _until(lambda: len(rogue.info.peers_zid()) == 2)
    time.sleep(1.0)
    base = key_base(mission)
    for step in range(ATTEMPTS):
        rogue.put(f"{base}/uav/0/msg", _bare(0, step))
        rogue.put(f"{base}/uav/0/msg", _signed_by(key_dir, mission, 1, 0, step))  # a member's key
    assert _until(lambda: receiver.stats.unauthenticated == 2 * ATTEMPTS), receiver.stats
    real.publish(0, _outbox(0, 0))
    assert receiver.wait_for(0, {0}, 15.0) == set()
    assert receiver.stats.received == 1


def test_the_view_joins_with_its_own_certificate_and_only_listens(stack: ExitStack, key_dir: Path) -> None:
    mission = _mission(key_dir)
    a, b = _member(stack, mission, 0), _member(stack, mission, 1)
    assert a.wait_alive({1}, 30.0) == set()
    view_keys = keys.for_mission(mission, "view")
    listener = MeshListener(build_world(mission, mission.seed, 0), view_keys)
    stack.callback(listener.close)
    assert _until(lambda: listener.status().connected, 30.0), listener.status()
    # the view's certificate cannot put anything: not as UAV 1, not anywhere
    snoop = _session(stack, mission, MeshSecurity.of(view_keys, mission))  # type: ignore[arg-type]
    assert _until(lambda: len(snoop.info.peers_zid()) >= 2)
    time.sleep(1.0)
    for step in range(ATTEMPTS):
        snoop.put(f"{key_base(mission)}/uav/1/msg", _bare(1, step))
    step = 0
    while listener.status().received < 4:  # bundles still reach the view (it subscribes late)
        a.publish(step, _outbox(0, step))
        b.publish(step, _outbox(1, step))
        assert step < 600, listener.status()
        step += 1
        time.sleep(0.05)
    time.sleep(QUIET_S - 2.0)
    assert listener.status().unauthenticated == listener.status().malformed == 0
    assert listener.status().secured
    for m in (a, b):
        s = m.stats
        assert (s.malformed, s.spoofed, s.unauthenticated, s.forged, s.duplicates) == (0, 0, 0, 0, 0), s
