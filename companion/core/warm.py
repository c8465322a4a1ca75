"""Kernel warm-up: a few agents fly a few steps so that numba compiles every kernel they use.

A fresh checkout compiles the core's kernels for tens of seconds, which a companion must not spend
inside its first real-time steps: it warms up before it flies (`companion.node.process`), and
`uavsearch run` warms up once before starting its companions, which then load the kernels from
numba's disk cache (`cache=True`).
"""

from __future__ import annotations

import math
import time

import msgspec
import numpy as np

from companion.contracts.mission import Mission
from companion.core.agent import Agent, Observation
from companion.core.connectivity import pairwise_distances
from companion.core.geometry import FloatArray
from companion.core.messages import Message
from companion.core.world import build_world

WARM_UP_STEPS = 30  # enough for bids, an auction and reevaluation (algorithm "proposed")
WARM_UP_UAVS = 4  # compiled code does not depend on the swarm's size


def warm_up(mission: Mission) -> float:
    """Compile or load every kernel the agents use; returns the seconds taken.

    Fly the agents of the mission's first few vehicles for a few steps, as the batch engine does
    (eq. 2 kinematics, messages delivered within R_c, a detection under each UAV at step 1), so
    that numba compiles every kernel they use or loads it from its disk cache. Returns the seconds
    taken."""
    started = time.perf_counter()
    small = msgspec.structs.replace(mission, vehicles=mission.vehicles[:WARM_UP_UAVS])
    world = build_world(small, small.seed, 0)
    agents = [Agent(world, i) for i in range(small.n_uavs)]
    poses = np.array([(v.x, v.y, math.radians(v.heading_deg)) for v in small.vehicles], dtype=float)
    inboxes: list[list[Message]] = [[] for _ in agents]
    for k in range(WARM_UP_STEPS):
        turns = np.empty(len(agents))
        outboxes: list[list[Message]] = []
        for i, agent in enumerate(agents):
            x, y, h = poses[i].tolist()
            seen = ((x, y),) if k == 1 else ()
            command, outbox = agent.step(
                Observation(step=k, x=x, y=y, heading=h, detections=seen), inboxes[i]
            )
            turns[i] = command.turn
            outboxes.append(outbox)
        inboxes = _deliver(poses[:, :2], outboxes, small.comms.range)
        poses = world.kinematics.advance_poses(poses, turns)
    return time.perf_counter() - started


def _deliver(positions: FloatArray, outboxes: list[list[Message]], comm_range: float) -> list[list[Message]]:
    """Each UAV's inbox: the messages of every other UAV within `comm_range`, by sender id."""
    n = len(outboxes)
    in_range = (pairwise_distances(positions) <= comm_range).tolist()
    return [[m for i in range(n) if i != j and in_range[i][j] for m in outboxes[i]] for j in range(n)]
