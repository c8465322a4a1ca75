"""Zenoh session configuration for the mesh: peer, client and router modes, loopback by default.

Multicast scouting is always off; peers gossip and, unless a launcher passes `listen`/`connect`,
claim the mission's seed endpoint (the first to bind it is the seed, the others connect to it).
A secured mesh (`MeshSecurity`, from the mission's key directory) runs every link over mutual TLS
with Zenoh access control. The configurations and the reasoning: docs/mesh.md, "Peer mode",
"Client mode and the router" and "Secured mesh"; docs/reliability.md, "The mesh".
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any, Literal

import zenoh

from companion.contracts.keys import ROLES, SwarmKeys, TlsFiles, uav_identity
from companion.contracts.mission import Mission

_SCOUTING_OFF = {"multicast": {"enabled": False}}
_SCOUTING_GOSSIP = {"multicast": {"enabled": False}, "gossip": {"enabled": True, "multihop": False}}


def key_base(mission: Mission) -> str:
    """`{prefix}/{mission}`: the mission's key space; raises ValueError if not a plain key."""
    base = f"{mission.mesh.key_prefix}/{mission.name}"
    chunks = base.split("/")
    if any(not c or any(ch in c for ch in "*$?#") for c in chunks):
        raise ValueError(f"mesh key prefix and mission name must make a plain Zenoh key: {base!r}")
    return base


@dataclass(frozen=True)
class MeshSecurity:
    """A secured mesh: this process's TLS files and what its access control needs to know."""

    tls: TlsFiles
    base: str
    n_uavs: int

    @classmethod
    def of(cls, keys: SwarmKeys, mission: Mission) -> MeshSecurity:
        return cls(keys.tls, key_base(mission), mission.n_uavs)


@dataclass(frozen=True)
class MeshConfig:
    """How one companion joins the mesh.

    `claim_seed`: an endpoint this peer first tries to listen on alone (see the module docstring);
    `listen`/`connect` are used when it is None or already taken. `security`: None for an
    insecure mesh (plain TCP, no access control).
    """

    mode: Literal["peer", "client"]
    listen: tuple[str, ...]
    connect: tuple[str, ...]
    claim_seed: str | None = None
    connect_timeout: float = 10.0
    security: MeshSecurity | None = None

    @classmethod
    def from_mission(
        cls,
        mission: Mission,
        listen: tuple[str, ...] | None = None,
        connect: tuple[str, ...] | None = None,
        keys: SwarmKeys | None = None,
    ) -> MeshConfig:
        """The mission's mesh settings, secured with `keys` when they are given.

        Explicit `listen`/`connect` (peer mode) disable seed claiming; `keys` (this process's, from the
        mission's key directory) secure it.
        """
        m = mission.mesh
        sec = None if keys is None else MeshSecurity.of(keys, mission)
        if m.mode == "client":
            return cls("client", (), (m.router,), None, m.connect_timeout, sec)
        if listen is not None or connect is not None:
            return cls("peer", listen or (), connect or (), None, m.connect_timeout, sec)
        return cls("peer", (m.listen,), (m.seed_endpoint,), m.seed_endpoint, m.connect_timeout, sec)


def peer_config(
    listen: tuple[str, ...], connect: tuple[str, ...], security: MeshSecurity | None = None
) -> zenoh.Config:
    """Peer mode: gossip on, multicast off."""
    return _config(
        {
            "mode": "peer",
            "listen": {"endpoints": list(listen)},
            "connect": {"endpoints": list(connect)},
            "scouting": _SCOUTING_GOSSIP,
        },
        security,
    )


def client_config(
    router: tuple[str, ...], timeout: float, security: MeshSecurity | None = None
) -> zenoh.Config:
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
        },
        security,
    )


def router_config(endpoint: str, security: MeshSecurity | None = None) -> zenoh.Config:
    """Router mode listening on `endpoint`, multicast off."""
    return _config(
        {"mode": "router", "listen": {"endpoints": [endpoint]}, "scouting": _SCOUTING_OFF}, security
    )


def open_session(cfg: MeshConfig) -> zenoh.Session:
    """Open a session for `cfg`, claiming the seed endpoint when configured and free."""
    if cfg.mode == "client":
        return zenoh.open(client_config(cfg.connect, cfg.connect_timeout, cfg.security))
    if cfg.claim_seed is not None:
        try:
            return zenoh.open(peer_config((cfg.claim_seed,), (), cfg.security))
        except zenoh.ZError:  # taken (or not ours to bind): join through it instead
            pass
    return zenoh.open(peer_config(cfg.listen, cfg.connect, cfg.security))


def secured_endpoint(endpoint: str) -> str:
    """`tcp/ADDR` as `tls/ADDR` (a secured mesh runs TLS only); `tls/` as it is; ValueError else."""
    if endpoint.startswith("tls/"):
        return endpoint
    if endpoint.startswith("tcp/"):
        return "tls/" + endpoint.removeprefix("tcp/")
    raise ValueError(f"a secured mesh runs over TLS: cannot secure the endpoint {endpoint!r}")


_LISTEN = ["declare_subscriber", "declare_liveliness_subscriber", "liveliness_query"]
_SPEAK = ["put", "liveliness_token"]


def access_control(security: MeshSecurity) -> dict[str, Any]:
    """Zenoh access control for the mission's key space, by certificate common name.

    Everyone may subscribe and have our puts (egress); UAV i may put on `uav/i/msg` and hold the
    token `alive/i`, the camera may put on `uav/*/camera`, the router may forward anything in the
    key space (it enforces the same rules at its own ingress), the view may only listen. Anything
    else, and anyone else, is denied.
    """
    base = security.base
    rules: list[dict[str, Any]] = [
        _rule("egress", "egress", _LISTEN + _SPEAK, [f"{base}/**"]),
        _rule("listen", "ingress", _LISTEN, [f"{base}/**"]),
        _rule("relay", "ingress", _SPEAK, [f"{base}/**"]),
        _rule("camera", "ingress", ["put"], [f"{base}/uav/*/camera"]),
    ]
    subjects = [{"id": role, "cert_common_names": [role]} for role in ROLES]
    policies = [
        {"rules": ["egress", "listen"], "subjects": ["view"]},
        {"rules": ["egress", "listen", "camera"], "subjects": ["camera"]},
        {"rules": ["egress", "listen", "relay"], "subjects": ["router"]},
    ]
    for i in range(security.n_uavs):
        who = uav_identity(i)
        rules.append(_rule(who, "ingress", _SPEAK, [f"{base}/uav/{i}/msg", f"{base}/alive/{i}"]))
        subjects.append({"id": who, "cert_common_names": [who]})
        policies.append({"rules": ["egress", "listen", who], "subjects": [who]})
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    }


def _rule(rule_id: str, flow: str, messages: list[str], keys: list[str]) -> dict[str, Any]:
    return {"id": rule_id, "permission": "allow", "flows": [flow], "messages": messages, "key_exprs": keys}


def _config(tree: dict[str, Any], security: MeshSecurity | None = None) -> zenoh.Config:
    """The Zenoh configuration of `tree` with shared memory off and, with `security`, TLS and access control.

    Shared memory off: large payloads would otherwise go through SHM segments between local
    processes, with two watchdog threads per process polling them (measured: a tenth of a core
    across 50 companions); the mesh's bundles are a few kilobytes and radio links have no SHM.

    With `security`: TLS endpoints, mutual authentication against the swarm's CA, access control.
    Peers are identified by their certificate, not by their address: the certificate's name is
    not checked against the address dialled (addresses change, the CA and the CN do not).
    """
    transport: dict[str, Any] = {"shared_memory": {"enabled": False}}
    if security is not None:
        tree = {
            **tree,
            **{
                part: {**tree[part], "endpoints": [secured_endpoint(e) for e in tree[part]["endpoints"]]}
                for part in ("listen", "connect")
                if part in tree
            },
            "access_control": access_control(security),
        }
        tls = security.tls
        transport["link"] = {
            "tls": {
                "root_ca_certificate": str(tls.ca),
                "enable_mtls": True,
                "listen_private_key": str(tls.key),
                "listen_certificate": str(tls.cert),
                "connect_private_key": str(tls.key),
                "connect_certificate": str(tls.cert),
                "verify_name_on_connect": False,
            }
        }
    return zenoh.Config.from_json5(json.dumps({**tree, "transport": transport}))
