"""A mesh peer in its own process: `peer_proc.py MISSION_JSON UAV PEERS STEPS`.

Prints "ready", waits for PEERS (comma-separated ids) to be alive, runs STEPS lockstep steps
(publish, wait for the peers' bundles, take the inbox) printing one JSON line per step, then
stays alive until stdin closes.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import msgspec
from mesh_helpers import N_CELLS, N_TASKS, outbox

from companion.contracts.mission import Mission
from companion.node.mesh import Mesh


def main(argv: list[str]) -> int:
    mission = msgspec.json.decode(Path(argv[0]).read_bytes(), type=Mission)
    uav, peers, steps = int(argv[1]), {int(p) for p in argv[2].split(",")}, int(argv[3])
    with Mesh(mission, uav, N_CELLS, N_TASKS) as mesh:
        print("ready", flush=True)
        mesh.wait_alive(peers, 20.0)
        for step in range(steps):
            x, y = 10.0 * uav, float(step)
            mesh.publish(step, outbox(uav, step, x, y))
            missing = mesh.wait_for(step, peers, 20.0)
            got = mesh.inbox(step + 1, (x, y))
            line = {"step": step, "missing": sorted(missing), "senders": [m.sender for m in got]}
            print(json.dumps(line), flush=True)
        sys.stdin.read()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
