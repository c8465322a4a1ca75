"""Mesh configuration: modes, loopback endpoints, multicast always off, key spaces."""

from __future__ import annotations

import json

import msgspec
import pytest
from mesh_helpers import make_mission

from companion.contracts.zenoh_config import MeshConfig, client_config, peer_config, router_config
from companion.node.mesh import key_base


def _get(config: object, key: str) -> object:
    return json.loads(config.get_json(key))  # type: ignore[attr-defined]


def test_peer_mode_claims_the_seed_by_default() -> None:
    m = make_mission()
    cfg = MeshConfig.from_mission(m)
    assert cfg == MeshConfig(
        "peer", ("tcp/127.0.0.1:0",), (m.mesh.seed_endpoint,), m.mesh.seed_endpoint, 10.0
    )


def test_explicit_endpoints_disable_seed_claiming() -> None:
    cfg = MeshConfig.from_mission(make_mission(), listen=("tcp/127.0.0.1:7001",), connect=())
    assert (cfg.listen, cfg.connect, cfg.claim_seed) == (("tcp/127.0.0.1:7001",), (), None)


def test_client_mode_connects_to_the_router() -> None:
    m = make_mission(mode="client", connect_timeout=2.5)
    assert MeshConfig.from_mission(m) == MeshConfig("client", (), (m.mesh.router,), None, 2.5)


def test_zenoh_configs_never_use_multicast() -> None:
    peer = peer_config(("tcp/127.0.0.1:0",), ("tcp/127.0.0.1:7450",))
    assert _get(peer, "mode") == "peer"
    assert _get(peer, "scouting/multicast/enabled") is False
    assert _get(peer, "scouting/gossip/enabled") is True
    assert _get(peer, "listen/endpoints") == ["tcp/127.0.0.1:0"]
    client = client_config(("tcp/127.0.0.1:7447",), 3.0)
    assert _get(client, "scouting/multicast/enabled") is False
    assert _get(client, "connect/endpoints") == ["tcp/127.0.0.1:7447"]
    router = router_config("tcp/127.0.0.1:7447")
    assert _get(router, "mode") == "router"
    assert _get(router, "scouting/multicast/enabled") is False


def test_key_base_and_bad_names() -> None:
    m = make_mission()
    assert key_base(m) == f"{m.mesh.key_prefix}/scenario1"
    for name in ("a*b", "x/", "$y", "q?"):
        with pytest.raises(ValueError, match="plain Zenoh key"):
            key_base(msgspec.structs.replace(m, name=name))
