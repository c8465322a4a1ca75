"""An autopilot's fence read back by pymavlink alone, and the fence a mission's companion uploads.

`read_fence` speaks the mission protocol itself (MISSION_REQUEST_LIST, MISSION_REQUEST_INT with
mission type FENCE) on a plain pymavlink connection: none of the companion's code reads it.
`plan_polygons` reads a QGroundControl .plan's GeoFence polygons straight from its JSON, so a test
can hold the fence against what the operator drew, not only against `fence.fence_items`.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from pathlib import Path

from pymavlink import mavutil

from companion.contracts.frames import LocalFrame
from companion.contracts.mission import Mission
from companion.node.fence import fence_items, fence_margin

FenceRow = tuple[int, float, int, int]  # command, param1 (vertex count or radius), lat and lon * 1e7
M = mavutil.mavlink
EXCLUSION = M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION
Message = M.MAVLink_message


def read_fence(conn: mavutil.mavfile, sysid: int, timeout: float = 60.0) -> list[FenceRow]:
    """System `sysid`'s fence over `conn` (each request retried until answered within `timeout`)."""
    fence = M.MAV_MISSION_TYPE_FENCE
    deadline = time.monotonic() + timeout

    def ask(send: Callable[[], None], kind: str, match: Callable[[Message], bool]) -> Message:
        while time.monotonic() < deadline:
            send()
            end = time.monotonic() + 2.0
            while (left := end - time.monotonic()) > 0:
                msg = conn.recv_match(type=kind, blocking=True, timeout=left)
                if msg is not None and msg.get_srcSystem() == sysid and match(msg):
                    return msg
        raise AssertionError(f"no {kind} from system {sysid}")

    count = ask(
        lambda: conn.mav.mission_request_list_send(sysid, 1, fence),
        "MISSION_COUNT",
        lambda m: m.mission_type == fence,
    ).count
    rows: list[FenceRow] = []
    for seq in range(count):
        it = ask(
            lambda s=seq: conn.mav.mission_request_int_send(sysid, 1, s, fence),
            "MISSION_ITEM_INT",
            lambda m, s=seq: m.mission_type == fence and m.seq == s,
        )
        rows.append((it.command, it.param1, it.x, it.y))
    conn.mav.mission_ack_send(sysid, 1, M.MAV_MISSION_ACCEPTED, fence)
    return rows


def companion_fence(mission: Mission) -> list[FenceRow]:
    """The fence a companion uploads for `mission` (preflight: the margin plus one step of slack)."""
    margin = fence_margin(mission) + mission.kinematics.speed * mission.kinematics.step
    items = fence_items(mission, LocalFrame(mission.region.origin), margin)
    return [(it.command, it.params[0], it.x, it.y) for it in items]


def plan_polygons(plan: Path, inclusion: bool) -> list[list[tuple[int, int]]]:
    """The inclusion (or exclusion) polygons of a .plan's GeoFence, (lat, lon) * 1e7 per vertex."""
    polygons = json.loads(plan.read_text(encoding="utf-8"))["geoFence"]["polygons"]
    return [
        [(round(lat * 1e7), round(lon * 1e7)) for lat, lon in p["polygon"]]
        for p in polygons
        if p["inclusion"] is inclusion
    ]


def assert_exclusions_as_drawn(rows: list[FenceRow], plan: Path) -> None:
    """The fence's exclusion polygons are the .plan's, vertex for vertex (1e-7 degrees of rounding)."""
    got = [(x, y) for command, _, x, y in rows if command == EXCLUSION]
    drawn = [v for p in plan_polygons(plan, inclusion=False) for v in p]
    assert len(got) == len(drawn), (got, drawn)
    for vertex in drawn:
        assert any(abs(x - vertex[0]) <= 1 and abs(y - vertex[1]) <= 1 for x, y in got), (vertex, got)
