"""A rogue process against a secured swarm (the fault matrix's rogue rows), on loopback only.

`python rogue.py outsider MISSION FOREIGN_KEYS`: no credentials of the swarm. It connects to the
mission's seed endpoint twice, in plain TCP and over TLS trusting the swarm's (public) CA with a
certificate from another CA (FOREIGN_KEYS, a key directory of its own), subscribes to everything
and puts a bundle naming UAV 1 every 0.1 s, until SIGINT/SIGTERM.

`python rogue.py insider MISSION ME VICTIM N`: UAV ME's mesh credentials and signing key (a
compromised member) but no MAVLink secret. Once every companion's liveliness token is seen, it
puts N bundles of each kind below; once the simulator's camera publishes (the vehicles are up), it
sends N unsigned and N wrongly signed MAVLink commands to every vehicle; then it exits:
  on_victim_key  naming VICTIM, on VICTIM's key, signed by ME   (access control drops them)
  spoofed        naming VICTIM, on ME's own key, signed by ME    (receivers count `spoofed`)
  forged         naming ME, relaying a state of VICTIM that ME signed (`forged`)
  wrong_key      naming ME, signed by a key the swarm does not list (`unauthenticated`)
  unsigned       naming ME, bare                                 (`unauthenticated`)

Both print one JSON line of what they did and saw when they end.
"""

from __future__ import annotations

import json
import os
import secrets
import signal
import sys
import threading
import time
from pathlib import Path

os.environ.setdefault("MAVLINK20", "1")
import zenoh
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey
from pymavlink import mavutil

from companion.contracts import keys
from companion.contracts.mission import Mission
from companion.contracts.zenoh_config import MeshSecurity, peer_config
from companion.core.feasibility import load_mission
from companion.core.messages import ClaimsMsg, CoverageMsg, Message, StateMsg, UavState
from companion.node.mesh import Bundle, encode_bundle, key_base, mission_authenticator
from companion.node.signing import Authenticator

STAMP = 1_000_000  # far beyond any step the swarm flies: nothing here could pass for a real bundle
ALIVE_S = 240.0
M = mavutil.mavlink


def _messages(sender: int, stamp: int, relayed: tuple[UavState, ...] = ()) -> tuple[Message, ...]:
    head = {"sender": sender, "stamp": stamp, "x": 0.0, "y": 0.0}
    state = UavState(uav=sender, stamp=stamp, x=0.0, y=0.0, heading=0.0, plan=())
    out: list[Message] = [StateMsg(**head, state=state), CoverageMsg(**head, cells=(0,), detections=(0,))]
    if relayed:
        out.append(ClaimsMsg(**head, known=relayed))
    return tuple(out)


def _bundle(sender: int, stamp: int, relayed: tuple[UavState, ...] = ()) -> Bundle:
    return Bundle(sender=sender, stamp=stamp, x=0.0, y=0.0, messages=_messages(sender, stamp, relayed))


def _sealed(auth: Authenticator, bundle: Bundle) -> bytes:
    return auth.seal(encode_bundle(bundle), bundle.messages)


def _report(**fields: object) -> None:
    print(json.dumps(fields), flush=True)


def outsider(mission: Mission, foreign: Path) -> int:
    stop = threading.Event()
    for s in (signal.SIGINT, signal.SIGTERM):
        signal.signal(s, lambda *_: stop.set())
    base = key_base(mission)
    mine = keys.load(foreign, "uav-1").tls
    trusting = keys.TlsFiles(Path(mission.security.keys) / "ca.pem", mine.cert, mine.key)
    securities = [None, MeshSecurity(trusting, base, mission.n_uavs)]
    heard = [0]
    seed = (mission.mesh.seed_endpoint,)
    sessions = [zenoh.open(peer_config(("tcp/127.0.0.1:0",), seed, sec)) for sec in securities]

    def on_sample(_sample: zenoh.Sample) -> None:
        heard[0] += 1

    remote = zenoh.Locality.REMOTE
    subs = [s.declare_subscriber(f"{base}/**", on_sample, allowed_origin=remote) for s in sessions]
    puts, peers_max, k = 0, 0, 0
    try:
        while not stop.wait(0.1):
            for s in sessions:
                s.put(f"{base}/uav/1/msg", encode_bundle(_bundle(1, STAMP + k)))
                puts += 1
                peers_max = max(peers_max, len(s.info.peers_zid()))
            k += 1
    finally:
        for sub in subs:
            sub.undeclare()
        for s in sessions:
            s.close()
    _report(role="outsider", puts=puts, peers_max=peers_max, received=heard[0])
    return 0


def insider(mission: Mission, me: int, victim: int, n: int) -> int:
    base = key_base(mission)
    creds = keys.for_mission(mission, keys.uav_identity(me))
    assert creds is not None
    auth = mission_authenticator(mission, creds)
    stranger = Authenticator(creds.public, base, Ed25519PrivateKey.generate())
    assert auth is not None
    alive: set[int] = set()
    cond = threading.Condition()
    camera = threading.Event()

    def on_token(sample: zenoh.Sample) -> None:
        with cond:
            alive.add(int(str(sample.key_expr).rsplit("/", 1)[-1]))
            cond.notify_all()

    sent: dict[str, int] = {}
    cfg = peer_config(("tcp/127.0.0.1:0",), (mission.mesh.seed_endpoint,), MeshSecurity.of(creds, mission))
    with zenoh.open(cfg) as s:
        tokens = s.liveliness().declare_subscriber(f"{base}/alive/*", on_token, history=True)
        frames = s.declare_subscriber(f"{base}/uav/*/camera", lambda _s: camera.set())
        with cond:
            cond.wait_for(lambda: len(alive) == mission.n_uavs, ALIVE_S)
        deadline = time.monotonic() + ALIVE_S  # gossip links us to every companion, not only the seed
        while len(s.info.peers_zid()) < mission.n_uavs and time.monotonic() < deadline:
            time.sleep(0.2)
        time.sleep(1.0)  # declarations behind the links settle
        victim_state = _messages(victim, STAMP)[0].state  # type: ignore[union-attr]
        attacks = {
            "on_victim_key": (victim, lambda j: _sealed(auth, _bundle(victim, STAMP + j))),
            "spoofed": (me, lambda j: _sealed(auth, _bundle(victim, STAMP + j))),
            "forged": (me, lambda j: _sealed(auth, _bundle(me, STAMP + j, (victim_state,)))),
            "wrong_key": (me, lambda j: _sealed(stranger, _bundle(me, STAMP + j))),
            "unsigned": (me, lambda j: encode_bundle(_bundle(me, STAMP + j))),
        }
        for name, (key_of, make) in attacks.items():
            for j in range(n):
                s.put(f"{base}/uav/{key_of}/msg", make(j))
            sent[name] = n
        peers = len(s.info.peers_zid())
        camera.wait(ALIVE_S)
        mavlink = _mavlink_attacks(mission, n)
        frames.undeclare()
        tokens.undeclare()
    _report(role="insider", sent=sent, mavlink=mavlink, peers=peers, alive=sorted(alive))
    return 0


def _mavlink_attacks(mission: Mission, n: int) -> dict[str, int]:
    """n unsigned and n wrongly signed DO_SET_MODE (RTL) commands to every vehicle."""
    out = {"unsigned": 0, "wrong_key": 0}
    for i in range(mission.n_uavs):
        for kind in out:
            conn = mavutil.mavlink_connection(
                f"udpout:127.0.0.1:{mission.vehicle_port(i)}", source_system=251, dialect="ardupilotmega"
            )
            if kind == "wrong_key":
                conn.setup_signing(secrets.token_bytes(32), sign_outgoing=True, link_id=7)
            for _ in range(n):
                conn.mav.command_long_send(i + 1, 1, M.MAV_CMD_DO_SET_MODE, 0, 1, 11, 0, 0, 0, 0, 0)
                out[kind] += 1
            conn.close()
    return out


def main(argv: list[str]) -> int:
    role, mission = argv[0], load_mission(argv[1])
    if role == "outsider":
        return outsider(mission, Path(argv[2]))
    return insider(mission, int(argv[2]), int(argv[3]), int(argv[4]))


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
