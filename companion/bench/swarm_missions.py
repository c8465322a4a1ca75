"""The benchmark's missions: a base mission's swarm grown to N vehicles on fresh loopback ports."""

from __future__ import annotations

import math
import os
import socket
from pathlib import Path

import msgspec

from companion.contracts.mission import Mission, Vehicle

DEFAULT_MISSION = Path(__file__).resolve().parents[2] / "mission_files" / "scenario1.toml"


def free_tcp_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def spread_vehicles(mission: Mission, n: int) -> list[Vehicle]:
    """n vehicles on a square grid centred in the region, on cell centres, heading north.

    Spacing: at most 400 m (well inside R_c = 1000 m, so the swarm starts connected) and at most
    the region's width over the grid's side (50 UAVs: ~260 m, far above R_s = 60 m).
    """
    from companion.core.world import build_grid  # local: keep the parent light

    grid = build_grid(mission)
    xs = [p[0] for p in mission.region.polygon]
    ys = [p[1] for p in mission.region.polygon]
    cx, cy = (min(xs) + max(xs)) / 2, (min(ys) + max(ys)) / 2
    side = math.ceil(math.sqrt(n))
    width = 0.9 * min(max(xs) - min(xs), max(ys) - min(ys))
    spacing = min(400.0, width / max(1, side - 1))
    out = []
    for i in range(n):
        x = cx + spacing * (i % side - (side - 1) / 2)
        y = cy + spacing * (i // side - (side - 1) / 2)
        x = grid.x0 + grid.cell_size * round((x - grid.x0) / grid.cell_size)
        y = grid.y0 + grid.cell_size * round((y - grid.y0) / grid.cell_size)
        out.append(Vehicle(x=float(x), y=float(y), heading_deg=90.0))
    return out


def bench_mission(base: Mission, n: int | None, mode: str, tag: str, keys: Path | None = None) -> Mission:
    """`base` made a trial's mission: its swarm, mesh mode, key prefix, ports and keys.

    `base` with n spread vehicles (None: its own), the mesh in `mode`, a unique key prefix,
    fresh loopback ports for the seed endpoint and the router and, with `keys`, secured by them."""
    vehicles = base.vehicles if n is None else spread_vehicles(base, n)
    mesh = msgspec.structs.replace(
        base.mesh,
        mode=mode,
        key_prefix=f"cbench{os.getpid()}{tag}",
        seed_endpoint=f"tcp/127.0.0.1:{free_tcp_port()}",
        router=f"tcp/127.0.0.1:{free_tcp_port()}",
        listen="tcp/127.0.0.1:0",
    )
    security = msgspec.structs.replace(base.security, keys=str(keys) if keys else "")
    return msgspec.structs.replace(base, vehicles=vehicles, mesh=mesh, security=security)

