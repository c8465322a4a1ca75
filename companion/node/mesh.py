"""The companion's peer-to-peer mesh over eclipse-zenoh: outbox out, validated and range-gated inbox in.

Each step a UAV puts one `Bundle` (its whole outbox, msgpack) on `{prefix}/{mission}/uav/{i}/msg`;
in a secured mesh, inside a signed `signing.Envelope`. Receipt runs in a Zenoh callback
thread: every sample is size-checked, decoded, validated (`check_bundle`) and, in a secured mesh,
authenticated; anything rejected is dropped, counted, and logged rate-limited per kind and sender
(`refusals`), nothing raises. Valid bundles wait in
a small per-sender buffer until `inbox(k)` takes those stamped k-1 and applies the batch engine's
radio: range gating at R_c and optional loss. Liveliness tokens on `{prefix}/{mission}/alive/{i}`
tell who is alive. `run_router`/`router_main` run a Zenoh router for client mode.
See docs/mesh.md.
"""

from __future__ import annotations

import argparse
import logging
import math
import signal
import sys
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from types import FrameType
from typing import Annotated, Any

import msgspec
import numpy as np
import zenoh

from companion.contracts.keys import KeyDirectoryError, SwarmKeys, for_mission, uav_identity, warn_if_insecure
from companion.contracts.mission import Mission, MissionError
from companion.contracts.wire import MsgpackCodec
from companion.contracts.zenoh_config import (
    MeshConfig,
    MeshSecurity,
    key_base,
    open_session,
    router_config,
    secured_endpoint,
)
from companion.core.feasibility import load_mission
from companion.core.messages import PROTOCOL_VERSION, Message, MessageError, check
from companion.node.refusals import Refusals
from companion.node.signing import Authenticator, Forged, Unauthenticated, decode_envelope

MAX_BUNDLE_MESSAGES = 32
HELD_STAMPS = 8  # bundles kept per sender (bounds memory whatever peers send)
DEFAULT_ROUTER_ENDPOINT = "tcp/127.0.0.1:7447"
# The router's main thread wakes this often: a SIGTERM that the kernel hands to one of Zenoh's
# threads only flags Python's handler, which runs when the main thread next runs Python code.
SIGNAL_POLL_S = 0.2
log = logging.getLogger("companion.mesh")


class Bundle(msgspec.Struct, frozen=True, kw_only=True):
    """One UAV's outbox of one step: header (version, sender, stamp, position) and its messages."""

    v: int = PROTOCOL_VERSION
    sender: int
    stamp: int
    x: float
    y: float
    messages: Annotated[tuple[Message, ...], msgspec.Meta(max_length=MAX_BUNDLE_MESSAGES)] = ()


_codec: MsgpackCodec[Bundle] = MsgpackCodec(Bundle, MessageError, "bundle")
encode_bundle = _codec.encode
decode_bundle = _codec.decode  # raises MessageError for anything undecodable


def check_bundle(bundle: Bundle, n_uavs: int, n_cells: int, n_tasks: int) -> None:
    """Raise MessageError unless the header is sane and every message is valid and matches it."""
    if bundle.v != PROTOCOL_VERSION:
        raise MessageError(f"bundle version {bundle.v}, expected {PROTOCOL_VERSION}")
    if not 0 <= bundle.sender < n_uavs:
        raise MessageError(f"unknown sender {bundle.sender}")
    if bundle.stamp < 0 or not (math.isfinite(bundle.x) and math.isfinite(bundle.y)):
        raise MessageError("bad stamp or position")
    for msg in bundle.messages:
        check(msg, n_uavs, n_cells, n_tasks)
        if (msg.sender, msg.stamp, msg.x, msg.y) != (bundle.sender, bundle.stamp, bundle.x, bundle.y):
            raise MessageError("message header differs from its bundle's")


class Spoofed(MessageError):
    """A bundle naming another sender than the UAV whose key it was put on."""


def received_bundle(
    sample: zenoh.Sample,
    max_bytes: int,
    n_uavs: int,
    n_cells: int,
    n_tasks: int,
    auth: Authenticator | None = None,
) -> Bundle:
    """The bundle in a sample from `{base}/uav/{i}/msg`, checked and authenticated.

    Size-checked, decoded, validated (`check_bundle`), sent by UAV i and, with `auth`, signed by it
    (states by their originators). Raises MessageError (a ValueError; `Spoofed`, `Unauthenticated`,
    `Forged` for what they say).
    """
    if len(sample.payload) > max_bytes:
        raise MessageError("oversized bundle")
    data = sample.payload.to_bytes()
    if auth is None:  # an insecure mesh: the bare bundle
        bundle = decode_bundle(data)
    else:
        try:
            envelope = decode_envelope(data)
        except MessageError:
            decode_bundle(data)  # malformed unless it is a bundle...
            raise Unauthenticated("unsigned bundle") from None  # ...which is not signed
        bundle = decode_bundle(envelope.body)
    check_bundle(bundle, n_uavs, n_cells, n_tasks)
    if str(sample.key_expr).split("/")[-2] != str(bundle.sender):
        raise Spoofed("sender differs from key")
    if auth is not None:
        auth.check(envelope, bundle.sender, bundle.messages)
    return bundle


def mission_authenticator(mission: Mission, keys: SwarmKeys | None) -> Authenticator | None:
    """What checks (and, with a UAV's keys, signs) bundles in this mission and run; None if insecure.

    It takes a rotated key from the key directory's swarm.json when one appears.
    """
    if keys is None:
        return None
    return Authenticator(keys.public, key_base(mission), keys.signing, keys.run, keys.reload_public)


@dataclass
class MeshStats:
    """Receipt counters of bundles and messages.

    Bundles: received (valid, from peers), malformed (dropped samples: oversized, undecodable, wrong
    version or sender, failed validation), spoofed (put on another UAV's key than the sender it
    names), unauthenticated (not signed by the sender it names), forged (carrying a state not signed
    by its UAV), stale (too old for their step, or evicted), duplicates (a second bundle for one
    sender and stamp).
    Messages: out_of_range (sender beyond R_c), lost (simulated loss).
    """

    received: int = 0
    malformed: int = 0
    spoofed: int = 0
    unauthenticated: int = 0
    forged: int = 0
    out_of_range: int = 0
    lost: int = 0
    stale: int = 0
    duplicates: int = 0

    @property
    def samples(self) -> int:
        """Samples taken or rejected: every sample that reached the subscriber is in one counter.

        Stale also counts evictions of held bundles.
        """
        return (
            self.received + self.malformed + self.spoofed + self.unauthenticated + self.forged
            + self.stale + self.duplicates
        )  # fmt: skip


class Mesh:
    """UAV `uav`'s mesh adapter: a context manager holding one Zenoh session.

    `n_cells`/`n_tasks` size the validation of incoming messages (n_uavs is `mission.n_uavs`);
    `rng` draws the simulated loss and is required when `mission.comms.loss > 0`; `keys` (this
    UAV's, `keys.for_mission`) sign what it sends and check what it receives, and secure the
    default configuration; `config` overrides `MeshConfig.from_mission(mission, keys=keys)`. With
    `join=False` the peers see this UAV alive only from `join()` on (a restarted companion joins once
    it can step: peers in lockstep wait for the bundles of every UAV they see alive).
    """

    def __init__(
        self,
        mission: Mission,
        uav: int,
        n_cells: int,
        n_tasks: int,
        rng: np.random.Generator | None = None,
        config: MeshConfig | None = None,
        join: bool = True,
        keys: SwarmKeys | None = None,
    ) -> None:
        if not 0 <= uav < mission.n_uavs:
            raise ValueError(f"uav {uav} not in 0..{mission.n_uavs - 1}")
        if mission.comms.loss > 0 and rng is None:
            raise ValueError("mission.comms.loss > 0 needs a seeded rng")
        self.uav, self.n_uavs, self.n_cells, self.n_tasks = uav, mission.n_uavs, n_cells, n_tasks
        self.comm_range, self.loss, self.rng = mission.comms.range, mission.comms.loss, rng
        self.max_bundle_bytes = mission.mesh.max_bundle_bytes
        base = key_base(mission)
        if keys is not None and keys.identity != uav_identity(uav):
            raise ValueError(f"UAV {uav} cannot join the mesh with the keys of {keys.identity}")
        self._auth = mission_authenticator(mission, keys)
        self._cond = threading.Condition()
        self._stats = MeshStats()
        self.refusals = Refusals(log, f"uav {uav}: mesh")
        self._held: dict[int, dict[int, Bundle]] = {}  # sender -> stamp -> bundle
        self._floor = 0  # bundles stamped below this are stale
        self._alive: set[int] = set()
        self._session = open_session(config or MeshConfig.from_mission(mission, keys=keys))
        try:  # the declared entities live as long as these references (and the session)
            self._publisher = self._session.declare_publisher(
                f"{base}/uav/{uav}/msg", congestion_control=zenoh.CongestionControl.BLOCK
            )
            self._subscriber = self._session.declare_subscriber(
                f"{base}/uav/*/msg", self._on_sample, allowed_origin=zenoh.Locality.REMOTE
            )
            self._alive_subscriber = self._session.liveliness().declare_subscriber(
                f"{base}/alive/*", self._on_liveliness, history=True
            )
            self._token_key = f"{base}/alive/{uav}"
            self._token: zenoh.LivelinessToken | None = None
            if join:
                self.join()  # last: see docs/mesh.md
        except BaseException:
            self._session.close()
            raise

    def join(self) -> None:
        """Declare this UAV alive (its liveliness token); idempotent."""
        if self._token is None:
            self._token = self._session.liveliness().declare_token(self._token_key)

    def leave(self) -> None:
        """Withdraw the liveliness token (a companion that cannot steer); idempotent.

        Peers take this UAV as gone until `join`.
        """
        if self._token is not None:
            self._token.undeclare()
            self._token = None

    # -- lifecycle ---------------------------------------------------------------------------------
    def __enter__(self) -> Mesh:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Close the session (idempotent): peers see our liveliness token go."""
        self._session.close()
        self.refusals.flush()
        with self._cond:
            self._cond.notify_all()

    @property
    def session(self) -> zenoh.Session:
        """The process's Zenoh session (shared with the camera subscription)."""
        return self._session

    @property
    def stats(self) -> MeshStats:
        """A snapshot of the counters."""
        with self._cond:
            return replace(self._stats)

    # -- sending -----------------------------------------------------------------------------------
    def publish(
        self, step: int, messages: list[Message], position: tuple[float, float] | None = None
    ) -> None:
        """Put the outbox of `step` as one bundle; the position defaults to the messages' own.

        Raises ValueError (MessageError) if peers would drop the bundle: our own bug, not theirs.
        """
        if position is None:
            if not messages:
                raise ValueError("an empty outbox needs the sender's position")
            position = (messages[0].x, messages[0].y)
        if self._auth is not None:
            messages = self._auth.relayable(messages)
        bundle = Bundle(
            sender=self.uav,
            stamp=step,
            x=float(position[0]),
            y=float(position[1]),
            messages=tuple(messages),
        )
        check_bundle(bundle, self.n_uavs, self.n_cells, self.n_tasks)
        data = encode_bundle(bundle)
        if self._auth is not None:
            data = self._auth.seal(data, bundle.messages)
        if len(data) > self.max_bundle_bytes:
            raise ValueError(f"bundle of {len(data)} bytes exceeds mesh.max_bundle_bytes")
        self._publisher.put(data)

    # -- receiving ---------------------------------------------------------------------------------
    def _on_sample(self, sample: zenoh.Sample) -> None:
        """Zenoh callback thread: validate, then hold; never raises, never blocks for long."""
        try:
            bundle = received_bundle(
                sample, self.max_bundle_bytes, self.n_uavs, self.n_cells, self.n_tasks, self._auth
            )
            if bundle.sender == self.uav:
                raise Spoofed("a bundle claiming our id")
        except (ValueError, msgspec.MsgspecError) as exc:  # MessageError is a ValueError
            with self._cond:
                kind = self._count_rejected(exc)
            self.refusals.refuse(f"{kind} bundle", f"key uav/{str(sample.key_expr).split('/')[-2]}", str(exc))
            return
        with self._cond:
            self._hold(bundle)
            self._cond.notify_all()

    def _count_rejected(self, exc: Exception) -> str:
        """Count a rejected sample; returns its kind."""
        s = self._stats
        if isinstance(exc, Spoofed):
            s.spoofed += 1
            return "spoofed"
        if isinstance(exc, Unauthenticated):
            s.unauthenticated += 1
            return "unauthenticated"
        if isinstance(exc, Forged):
            s.forged += 1
            return "forged"
        s.malformed += 1
        return "malformed"

    def _hold(self, bundle: Bundle) -> None:
        s = self._stats
        held = self._held.setdefault(bundle.sender, {})
        if bundle.stamp < self._floor:
            s.stale += 1
        elif bundle.stamp in held:
            s.duplicates += 1
        else:
            s.received += 1
            held[bundle.stamp] = bundle
            if len(held) > HELD_STAMPS:
                del held[min(held)]
                s.stale += 1

    def inbox(self, step: int, own_position_at_sender_step: Sequence[float]) -> list[Message]:
        """Messages of the bundles stamped step-1 that the batch engine's radio would deliver.

        Gating: a bundle is kept iff the distance between its sender's position and ours, both at
        step-1, is <= R_c (computed as the engine does). Loss: then each message is dropped with
        probability `loss`, one draw of `rng` per in-range message in delivery order, so a
        receiver's draws depend only on its own seed and what it received. Order: by sender id,
        then outbox order. Older bundles are dropped as stale, and so are any arriving later.
        """
        ox, oy = float(own_position_at_sender_step[0]), float(own_position_at_sender_step[1])
        out: list[Message] = []
        with self._cond:
            s = self._stats
            self._floor = max(self._floor, step)
            for sender in sorted(self._held):
                held = self._held[sender]
                for stamp in [t for t in held if t < step]:
                    bundle = held.pop(stamp)
                    if stamp != step - 1:
                        s.stale += 1
                        continue
                    dx, dy = bundle.x - ox, bundle.y - oy
                    if math.sqrt(dx * dx + dy * dy) > self.comm_range:
                        s.out_of_range += len(bundle.messages)
                        continue
                    for msg in bundle.messages:
                        if self.loss > 0 and self.rng is not None and self.rng.random() < self.loss:
                            s.lost += 1
                        else:
                            out.append(msg)
        return out

    def wait_for(self, step: int, peers: set[int], timeout: float) -> set[int]:
        """Block until every peer's bundle stamped `step` is held; return the peers still missing.

        Call it before `inbox(step + 1)` takes them. It returns early, too, once those missing have left,
        or after `timeout` s; the peers it returns are those still missing (and alive).
        """
        deadline = time.monotonic() + timeout
        with self._cond:
            while True:
                missing = {p for p in peers if step not in self._held.get(p, {}) and p in self._alive}
                remaining = deadline - time.monotonic()
                if not missing or remaining <= 0 or self._session.is_closed():
                    return missing
                self._cond.wait(remaining)

    # -- liveliness --------------------------------------------------------------------------------
    def _on_liveliness(self, sample: zenoh.Sample) -> None:
        try:
            uav = int(str(sample.key_expr).rsplit("/", 1)[-1])
        except ValueError:
            return
        if uav == self.uav or not 0 <= uav < self.n_uavs:
            return
        with self._cond:
            if sample.kind == zenoh.SampleKind.PUT:
                self._alive.add(uav)
            else:
                self._alive.discard(uav)
            self._cond.notify_all()

    def alive_peers(self) -> set[int]:
        """The other UAVs whose companions are alive now (liveliness tokens)."""
        with self._cond:
            return set(self._alive)

    def wait_alive(self, peers: set[int], timeout: float) -> set[int]:
        """Block until all `peers` are alive or `timeout` s pass; return those not alive."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while True:
                missing = peers - self._alive
                remaining = deadline - time.monotonic()
                if not missing or remaining <= 0 or self._session.is_closed():
                    return missing
                self._cond.wait(remaining)


# -- router ----------------------------------------------------------------------------------------
def run_router(
    endpoint: str = DEFAULT_ROUTER_ENDPOINT,
    stop: threading.Event | None = None,
    security: MeshSecurity | None = None,
) -> None:
    """Run a Zenoh router on `endpoint` until SIGINT/SIGTERM (main thread only) or `stop` is set.

    With `security` (the router's keys) it runs over TLS with the mesh's access control.
    """
    if stop is None:
        stop = threading.Event()
    previous: dict[signal.Signals, Any] = {}
    if threading.current_thread() is threading.main_thread():

        def on_signal(_signum: int, _frame: FrameType | None) -> None:
            stop.set()

        for sig in (signal.SIGINT, signal.SIGTERM):
            previous[sig] = signal.signal(sig, on_signal)
    try:
        with zenoh.open(router_config(endpoint, security)):
            shown = f"{secured_endpoint(endpoint)} (mutual TLS, access control)" if security else endpoint
            print(f"router listening on {shown}", flush=True)
            while not stop.wait(SIGNAL_POLL_S):
                pass
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def router_main(argv: Sequence[str] | None = None) -> int:
    """`uavsearch router [--endpoint E | --mission FILE]`: exit 0 on SIGINT/SIGTERM."""
    parser = argparse.ArgumentParser(
        prog="uavsearch router", description="Run a Zenoh router for client mode."
    )
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--endpoint", help=f"listen endpoint (default {DEFAULT_ROUTER_ENDPOINT})")
    group.add_argument("--mission", help="mission file: listen on its mesh.router endpoint")
    args = parser.parse_args(argv)
    endpoint = args.endpoint or DEFAULT_ROUTER_ENDPOINT
    security = None
    try:
        if args.mission:
            mission = load_mission(args.mission)
            endpoint = mission.mesh.router
            warn_if_insecure(mission)
            keys = for_mission(mission, "router")
            security = None if keys is None else MeshSecurity.of(keys, mission)
        run_router(endpoint, security=security)
    except (MissionError, KeyDirectoryError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except zenoh.ZError as exc:
        print(f"error: cannot run a router on {endpoint}: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    if sys.argv[1:2] != ["router"]:
        sys.exit("usage: python -m companion.node.mesh router [--endpoint E | --mission FILE]")
    sys.exit(router_main(sys.argv[2:]))
