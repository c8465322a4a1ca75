"""The cost of signing and checking the mesh's bundles, measured in one process."""

from __future__ import annotations

import math
import time
from typing import Any

import msgspec
import numpy as np

from companion.contracts.mission import Mission


class SigningCost(msgspec.Struct, frozen=True):
    """Median microseconds to sign a bundle and to check one, over `bundles` bundles."""

    seal_us_median: float
    check_us_median: float
    bundles: int


def signing_cost(mission: Mission, steps: int = 60) -> SigningCost:
    """Microseconds per bundle to sign and to check, over `steps` steps of the mission's agents.

    Microseconds per bundle to sign (`Authenticator.relayable` + `seal`) and to check (`check`,
    each receiver keeping its checked signatures, as the mesh does): the mission's agents step
    together in one process, everyone hearing everyone, and every outbox is sealed by its sender
    and checked by every other UAV. `mission` must name a key directory."""
    from companion.contracts.keys import for_mission, uav_identity
    from companion.core.agent import Agent, Observation
    from companion.core.world import build_world
    from companion.node.mesh import Bundle, encode_bundle, key_base
    from companion.node.signing import Authenticator, decode_envelope

    world = build_world(mission, mission.seed, 0)
    n = mission.n_uavs
    auths = []
    for i in range(n):
        keys = for_mission(mission, uav_identity(i))
        assert keys is not None, "signing_cost needs a mission with keys"
        auths.append(Authenticator(keys.public, key_base(mission), keys.signing))
    agents = [Agent(world, i) for i in range(n)]
    poses = [(v.x, v.y, math.radians(v.heading_deg)) for v in mission.vehicles]
    boxes: list[list[Any]] = [[] for _ in range(n)]
    seal_us: list[float] = []
    check_us: list[float] = []
    for k in range(steps):
        out = [
            a.step(Observation(step=k, x=p[0], y=p[1], heading=p[2]), box)
            for a, p, box in zip(agents, poses, boxes, strict=True)
        ]
        boxes = [[] for _ in range(n)]
        for i, (_, outbox) in enumerate(out):
            t0 = time.perf_counter()
            msgs = auths[i].relayable(outbox)
            bundle = Bundle(sender=i, stamp=k, x=poses[i][0], y=poses[i][1], messages=tuple(msgs))
            wire = auths[i].seal(encode_bundle(bundle), bundle.messages)
            seal_us.append(1e6 * (time.perf_counter() - t0))
            envelope = decode_envelope(wire)
            for j in range(n):
                if j != i:
                    t0 = time.perf_counter()
                    auths[j].check(envelope, i, bundle.messages)
                    check_us.append(1e6 * (time.perf_counter() - t0))
                    boxes[j].extend(msgs)
        poses = [
            tuple(float(v) for v in world.kinematics.advance(*p, c.turn))  # type: ignore[misc]
            for p, (c, _) in zip(poses, out, strict=True)
        ]
    return SigningCost(float(np.median(seal_us)), float(np.median(check_us)), len(seal_us))
