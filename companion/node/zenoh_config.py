"""Zenoh session configuration for the mesh: peer, client and router modes, loopback by default.

Every configuration built here turns multicast scouting off (never join 224.0.0.224) and, for
peers, turns gossip scouting on so that peers that only know one seed endpoint find each other.

Peer discovery without a launcher ("claim the seed"): every peer first tries to listen on the
mission's seed endpoint itself; the first one to bind it is the seed. A peer that finds the port
taken listens on `mission.mesh.listen` (port 0 by default) and connects to the seed instead;
gossip then forms the full mesh. Any subset of peers started in any order finds each other, and
when the seed's holder dies, the next peer to start claims the port and the others reconnect to
it (Zenoh retries configured connect endpoints). A launcher that prefers fixed endpoints passes
`listen`/`connect` explicitly, and then nobody claims the seed.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Literal

import zenoh

from companion.mission import Mission

_SCOUTING_OFF = {"multicast": {"enabled": False}}
_SCOUTING_GOSSIP = {"multicast": {"enabled": False}, "gossip": {"enabled": True, "multihop": False}}


@dataclass(frozen=True)
class MeshConfig:
    """How one companion joins the mesh.

    `claim_seed`: an endpoint this peer first tries to listen on alone (see the module docstring);
    `listen`/`connect` are used when it is None or already taken.
    """

    mode: Literal["peer", "client"]
    listen: tuple[str, ...]
    connect: tuple[str, ...]
    claim_seed: str | None = None
    connect_timeout: float = 10.0

    @classmethod
    def from_mission(
        cls,
        mission: Mission,
        listen: tuple[str, ...] | None = None,
        connect: tuple[str, ...] | None = None,
    ) -> MeshConfig:
        """The mission's mesh settings; explicit `listen`/`connect` (peer mode) disable seed claiming."""
        m = mission.mesh
        if m.mode == "client":
            return cls("client", (), (m.router,), None, m.connect_timeout)
        if listen is not None or connect is not None:
            return cls("peer", listen or (), connect or (), None, m.connect_timeout)
        return cls("peer", (m.listen,), (m.seed_endpoint,), m.seed_endpoint, m.connect_timeout)


def peer_config(listen: tuple[str, ...], connect: tuple[str, ...]) -> zenoh.Config:
    """Peer mode: gossip on, multicast off."""
    return _config(
        {
            "mode": "peer",
            "listen": {"endpoints": list(listen)},
            "connect": {"endpoints": list(connect)},
            "scouting": _SCOUTING_GOSSIP,
        }
    )


def client_config(router: tuple[str, ...], timeout: float) -> zenoh.Config:
    """Client mode: wait up to `timeout` s for a router (retrying every <= 1 s), multicast off."""
    return _config(
        {
            "mode": "client",
            "connect": {
                "endpoints": list(router),
                "timeout_ms": round(timeout * 1000),
                "exit_on_failure": True,
                "retry": {"period_init_ms": 250, "period_max_ms": 1000, "period_increase_factor": 2},
            },
            "scouting": _SCOUTING_OFF,
        }
    )


def router_config(endpoint: str) -> zenoh.Config:
    """Router mode listening on `endpoint`, multicast off."""
    return _config({"mode": "router", "listen": {"endpoints": [endpoint]}, "scouting": _SCOUTING_OFF})


def open_session(cfg: MeshConfig) -> zenoh.Session:
    """Open a session for `cfg`, claiming the seed endpoint when configured and free."""
    if cfg.mode == "client":
        return zenoh.open(client_config(cfg.connect, cfg.connect_timeout))
    if cfg.claim_seed is not None:
        try:
            return zenoh.open(peer_config((cfg.claim_seed,), ()))
        except zenoh.ZError:  # taken (or not ours to bind): join through it instead
            pass
    return zenoh.open(peer_config(cfg.listen, cfg.connect))


def _config(tree: dict) -> zenoh.Config:
    """Shared memory off: large payloads would otherwise go through SHM segments between local
    processes, with two watchdog threads per process polling them (measured: a tenth of a core
    across 50 companions); the mesh's bundles are a few kilobytes and radio links have no SHM."""
    return zenoh.Config.from_json5(json.dumps({**tree, "transport": {"shared_memory": {"enabled": False}}}))
