"""A restarted companion that this one holds no liveliness token of (docs/mesh.md, "Liveliness"):
real Zenoh sessions on 127.0.0.1, the real agents, and the companion's `Departures`, stepped in
lockstep by hand. UAV 1's companion dies (its session closes, its token goes) and comes back with a
new session that never declares its token. Its messages still reach UAV 0: UAV 0 keeps it from
then on, even at a step whose bundle from it comes too late (a peer without a token is not waited
for), as it keeps any peer until the agent's peer timeout."""

from __future__ import annotations

from contextlib import ExitStack

from mesh_helpers import make_mission, until

from companion.core.agent import Agent, Observation
from companion.core.world import build_world
from companion.node.departures import Departures
from companion.node.mesh import Mesh

POSITIONS = {0: (-300.0, 0.0), 1: (300.0, 0.0), 2: (0.0, 300.0)}


def _holds(mesh: Mesh, step: int, senders: set[int]) -> bool:
    return all(step in mesh._held.get(v, {}) for v in senders)


def test_a_restarted_peer_without_its_token_is_kept() -> None:
    with ExitStack() as stack:
        _fly(stack)


def _fly(stack: ExitStack) -> None:
    mission = make_mission()
    world = build_world(mission)
    n_tasks = world.tessellation.n_tasks if world.tessellation else 0

    def open_mesh(uav: int, join: bool = True) -> Mesh:  # sized as the companion sizes it
        return stack.enter_context(Mesh(mission, uav, world.grid.n_cells, n_tasks, join=join))

    meshes = {u: open_mesh(u) for u in POSITIONS}
    agents = {u: Agent(world, u) for u in POSITIONS}
    departures = Departures()  # UAV 0's
    back: list[int] = []

    def step(k: int, silent: frozenset[int] = frozenset()) -> None:
        """Step k of every flying UAV (UAV 0's departures first, as `Pilot.step` does); the
        bundles of those `silent` come too late for step k + 1 (they are not sent)."""
        change = departures.update(k, meshes[0].alive_peers(), agents[0].peers)
        back.extend(change.back)
        for u in change.forget:
            agents[0].forget(u)
        for u, mesh in meshes.items():
            x, y = POSITIONS[u]
            _, outbox = agents[u].step(Observation(step=k, x=x, y=y, heading=0.0), mesh.inbox(k, (x, y)))
            if u not in silent:
                mesh.publish(k, outbox, position=(x, y))
        for u in meshes:  # lockstep: every bundle sent is held before step k + 1
            assert until(lambda u=u: _holds(meshes[u], k, set(meshes) - silent - {u}), 15.0), (u, k)

    assert until(lambda: meshes[0].alive_peers() == {1, 2}, 15.0)
    for k in range(3):
        step(k)
    assert set(agents[0].peers) == {1, 2}

    meshes.pop(1).close()  # UAV 1's companion dies: its token goes
    assert until(lambda: meshes[0].alive_peers() == {2}, 15.0)
    step(3)  # its last bundle (of step 2) still comes in
    step(4)
    assert set(agents[0].peers) == {2}  # forgotten: its task is free

    meshes[1] = open_mesh(1, join=False)  # back, on a new session that holds no token
    agents[1] = Agent(world, 1)
    assert until(lambda: meshes[1].alive_peers() == {0, 2}, 15.0)  # their subscriptions known there
    assert meshes[0].alive_peers() == {2}
    for k in range(5, 9):
        step(k)
    assert back == [1] and set(agents[0].peers) == {1, 2}
    step(9, silent=frozenset({1}))
    step(10)  # nothing of UAV 1 reaches UAV 0 at this step (UAV 0 heard it first-hand: no relay)
    assert set(agents[0].peers) == {1, 2}, "a peer heard of after it left is kept like any other"
