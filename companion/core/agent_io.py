"""What an agent takes and gives: its observation, command, step delta and snapshot."""

from __future__ import annotations

import msgspec

from companion.core.trajectory import Trajectory


class Observation(msgspec.Struct, frozen=True, kw_only=True):
    """The UAV's own pose at step k, its camera's detections and whether it steers its vehicle.

    The UAV's own pose at step k (local frame, heading CCW from east), its camera's detections,
    and whether its vehicle flies what the agent commands (False: a pilot, a failsafe or the guard's
    way back inside flies it; the agent then commits to nothing: `UavState.steered`). `closing`: the
    mission is over; the agent proposes nothing new and commands its trajectory in force, which ends
    in a loiter that every peer's trajectory in force keeps clear of (the companion's hand-over).
    `looked`: whether the camera took a picture over the step (the companion: a frame arrived);
    without one the step adds no evidence to the target map (`core.belief`)."""

    step: int
    x: float
    y: float
    heading: float
    detections: tuple[tuple[float, float], ...] = ()
    steered: bool = True
    closing: bool = False
    looked: bool = True


class StepDelta(msgspec.Struct, frozen=True, array_like=True):
    """What one step changed in an agent's own knowledge (`Agent.last`).

    What one step changed in an agent's own knowledge (`Agent.last`): every FOV cell applied to its
    map (its own and its neighbours', in order), the cells newly confirmed, its task and commitments
    after the step, and every evidence record its target-probability map took (`core.belief`).
    Replaying the deltas of steps k+1..k' on the snapshot of step k (`Agent.replay`) gives the
    agent's maps, targets, task and trajectory in force of step k'."""

    step: int
    looks: tuple[int, ...]
    found: tuple[int, ...]
    task: int
    task_reward: float
    inforce: Trajectory
    parents: tuple[int, ...]
    records: tuple[int, ...] = ()
    record_values: tuple[float, ...] = ()


class AgentSnapshot(msgspec.Struct, frozen=True, array_like=True):
    """An agent's own knowledge after step `step` (`Agent.snapshot`, `Agent.restore`).

    An agent's own knowledge after step `step` (`Agent.snapshot`, `Agent.restore`): its uncertainty
    map (float64, little-endian), the cells it has looked at (packed bits), the cells it holds confirmed,
    its task, its trajectory in force and tethers, the pheromone field (that algorithm only) and its
    target-probability map's evidence (`Belief.to_bytes`).
    What it knew of the others is not kept: their next messages tell it again."""

    uav: int
    step: int
    eta: bytes
    seen: bytes
    found: tuple[int, ...]
    task: int
    task_reward: float
    inforce: Trajectory
    parents: tuple[int, ...]
    phi: bytes | None = None
    evidence: bytes = b""
    evidence_stamps: bytes = b""


class Command(msgspec.Struct, frozen=True, kw_only=True):
    """The first step of the chosen path: turn over the step, and the path for waypoint autopilots."""

    step: int
    turn: float
    heading_rate: float
    heading: float
    waypoint: tuple[float, float]
    path: tuple[tuple[float, float], ...]
    task: int = -1
