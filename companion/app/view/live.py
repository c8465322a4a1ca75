"""A read-only listener on a mission's mesh: the frames of a flying swarm, as they happen.

The listener opens its own Zenoh session (peer or client, as the mission's mesh) and only
subscribes: to every UAV's bundles and to the liveliness tokens. It declares no publisher and no
liveliness token (companions would take a token for a UAV), and in peer mode it never claims the
seed endpoint: it listens on `mesh.listen` and connects to the seed, retrying until a companion
holds it. Samples go through Zenoh ring channels, which drop the oldest when the listener falls
behind instead of blocking Zenoh's network threads, so a slow viewer never holds up the swarm.
Every bundle is checked with the mesh's own `received_bundle`; anything malformed is counted and
dropped. In a secured mesh the listener joins with the view's own certificate (access control lets
it subscribe and nothing else) and checks every bundle's signatures like a companion; what fails
is counted as unauthenticated and dropped.
"""

from __future__ import annotations

import logging
import threading
import time

import msgspec
import zenoh

from companion.app.view.swarm_model import Report, SwarmModel
from companion.contracts.keys import SwarmKeys
from companion.contracts.zenoh_config import MeshConfig, open_session
from companion.core.world import World
from companion.node.mesh import Spoofed, key_base, mission_authenticator, received_bundle
from companion.node.refusals import Refusals
from companion.node.signing import Forged, Unauthenticated

RING_PER_UAV = 64  # samples buffered per UAV before the oldest are dropped
RETRY_S = 1.0  # between attempts to open the session (a client waiting for its router)
TICK_S = 0.2  # how often steps waiting for silent UAVs are re-examined
MAX_FRAMES = 100_000  # steps kept for the pages (about 10 MB for 4 UAVs)


class ListenerStatus(msgspec.Struct, frozen=True):
    """What the listener has seen (/api/status).

    The session, the UAVs alive, the bundles received, dropped (malformed, unauthenticated) and
    refused (kind -> sender -> count), the reports that came after their step closed (`late`) and
    the last closed step."""

    connected: bool
    error: str
    alive: list[int]
    received: int
    malformed: int
    unauthenticated: int
    refused: dict[str, dict[str, int]]
    secured: bool
    late: int
    step: int


def listener_config(world: World, keys: SwarmKeys | None = None) -> MeshConfig:
    """The mission's mesh, joined without claiming the seed.

    The mission's mesh, joined without claiming the seed: a peer listens on `mesh.listen` and
    connects to the seed endpoint; a client connects to the router. `keys`: the view's own."""
    m = world.mission.mesh
    if m.mode == "client":
        return MeshConfig.from_mission(world.mission, keys=keys)
    return MeshConfig.from_mission(world.mission, listen=(m.listen,), connect=(m.seed_endpoint,), keys=keys)


class MeshListener:
    """A read-only follower of the mesh of `world.mission`, on background threads.

    Follows the mesh of `world.mission` on background threads; `frames_since` and `status` are
    safe to call from any thread. `close` ends the session and the threads. `keys`: the view's
    own (`keys.for_mission(mission, "view")`) for a secured mesh."""

    def __init__(self, world: World, keys: SwarmKeys | None = None) -> None:
        m = world.mission
        self.world, self.base, self.keys = world, key_base(m), keys
        self._auth = mission_authenticator(m, keys)
        self.n_cells = world.grid.n_cells
        self.n_tasks = world.tessellation.n_tasks if world.tessellation else 0
        self.model = SwarmModel(
            m.n_uavs,
            self.n_cells,
            m.uncertainty.eta0,
            m.uncertainty.gamma,
            m.comms.range,
            m.comms.peer_timeout_steps,
        )
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._frames: list[str] = []
        self._first = 0  # index of _frames[0] among all frames made
        self.alive: set[int] = set()
        self.received = self.malformed = self.unauthenticated = 0
        self.refusals = Refusals(logging.getLogger("companion.view"), "view: mesh")
        self.session: zenoh.Session | None = None
        self.error = ""
        self._threads = [threading.Thread(target=self._run, name="view-mesh", daemon=True)]
        self._threads[0].start()

    # -- threads -----------------------------------------------------------------------------------
    def _open(self) -> zenoh.Session | None:
        cfg = listener_config(self.world, self.keys)
        while not self._stop.is_set():
            try:
                return open_session(cfg)
            except zenoh.ZError as exc:
                self.error = f"cannot join the mesh yet: {exc}"
                self._stop.wait(RETRY_S)
        return None

    def _run(self) -> None:
        session = self._open()
        if session is None:
            return
        try:
            n = self.world.mission.n_uavs
            bundles = session.declare_subscriber(
                f"{self.base}/uav/*/msg", zenoh.handlers.RingChannel(RING_PER_UAV * n)
            )
            tokens = session.liveliness().declare_subscriber(
                f"{self.base}/alive/*", zenoh.handlers.RingChannel(16 * n), history=True
            )
        except BaseException:
            session.close()
            raise
        with self._lock:
            self.session, self.error = session, ""
        if self._stop.is_set():  # closed while opening
            session.close()
            return
        workers = [
            threading.Thread(target=self._drain_bundles, args=(bundles,), daemon=True),
            threading.Thread(target=self._drain_tokens, args=(tokens,), daemon=True),
        ]
        for t in workers:
            t.start()
        while not self._stop.wait(TICK_S):
            with self._lock:
                self._keep(self.model.close_ready(time.monotonic()))
        for t in workers:
            t.join(5)

    def _drain_bundles(self, sub: zenoh.Subscriber) -> None:
        max_bytes = self.world.mission.mesh.max_bundle_bytes
        n = self.world.mission.n_uavs
        for sample in sub.handler:  # ends when the session closes
            try:
                bundle = received_bundle(sample, max_bytes, n, self.n_cells, self.n_tasks, self._auth)
                report = Report.of(bundle)
            except (Spoofed, Unauthenticated, Forged) as exc:
                with self._lock:
                    self.unauthenticated += 1
                kind = {Spoofed: "spoofed", Unauthenticated: "unauthenticated", Forged: "forged"}[type(exc)]
                self.refusals.refuse(f"{kind} bundle", f"key uav/{str(sample.key_expr).split('/')[-2]}")
                continue
            except (ValueError, msgspec.MsgspecError):
                with self._lock:
                    self.malformed += 1
                continue
            with self._lock:
                self.received += 1
                self.model.add(report, time.monotonic())
                self._keep(self.model.close_ready(time.monotonic()))

    def _drain_tokens(self, sub: zenoh.Subscriber) -> None:
        for sample in sub.handler:
            try:
                uav = int(str(sample.key_expr).rsplit("/", 1)[-1])
            except ValueError:
                continue
            if not 0 <= uav < self.world.mission.n_uavs:
                continue
            alive = sample.kind == zenoh.SampleKind.PUT
            with self._lock:
                self.model.set_alive(uav, alive)
                (self.alive.add if alive else self.alive.discard)(uav)

    def _keep(self, frames: list[str]) -> None:
        self._frames.extend(frames)
        extra = len(self._frames) - MAX_FRAMES
        if extra > 0:
            del self._frames[:extra]
            self._first += extra

    # -- readers -----------------------------------------------------------------------------------
    def frames_since(self, n: int) -> tuple[int, list[str]]:
        """The frames from the n-th made on (as many as are still kept), and the count made so far."""
        with self._lock:
            start = max(n, self._first)
            return self._first + len(self._frames), self._frames[start - self._first :]

    def status(self) -> ListenerStatus:
        """The listener's counters (`ListenerStatus`)."""
        with self._lock:
            return ListenerStatus(
                connected=self.session is not None,
                error=self.error,
                alive=sorted(self.alive),
                received=self.received,
                malformed=self.malformed,
                unauthenticated=self.unauthenticated,
                refused=self.refusals.summary(),
                secured=self.keys is not None,
                late=self.model.late,
                step=self.model.closed,
            )

    def close(self) -> None:
        """End the session (idempotent) and the listener's threads."""
        self._stop.set()
        with self._lock:
            session = self.session
        if session is not None:
            session.close()
        for t in self._threads:
            t.join(self.world.mission.mesh.connect_timeout + 5)  # a client may be inside zenoh.open
