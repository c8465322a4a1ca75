"""The companion's end-of-run report (`uav<N>.json`): what it learned and what it refused."""

from __future__ import annotations

import msgspec

from companion.node.mesh import MeshStats
from companion.node.tracking import PlanSummary


class CompanionReport(msgspec.Struct, frozen=True):
    """One companion's record of its run, written next to its logs when it closes."""

    uav: int
    steps: int
    found_cells: list[int]  # confirmed at the end (`Agent.found`)
    candidate_cells: list[int]  # undecided at the end (`Agent.candidates`)
    candidates_raised: int  # target log events since this process started (`TargetWatch`)
    confirmations: int
    retractions: int
    task: int
    rejected_mavlink: int
    mavlink_signed: bool
    mavlink_unauthenticated: int
    mavlink_wrong_system: int
    refused: dict[str, dict[str, dict[str, int]]]  # mesh / mavlink -> kind -> sender -> count
    rejected_camera: int
    mesh: MeshStats
    plan_vs_flight: PlanSummary
    command_mode: str
    airframe_warnings: list[str]
    fence_uploaded: bool
    failsafe_armed: bool
    failsafe_uploads: int
    fence_exits: int
    guard: str
    restarted_from_step: int
    fault_dropped: int
    journal_records: int | None
