"""Versioned mesh messages between agents: state, coverage/detections, bids and claims.

Every message carries the protocol version, its sender's id, the step it was produced at (its
sequence number) and the sender's position at that step (for range gating on receipt). Messages
are immutable msgspec structs; `encode`/`decode` give the msgpack wire form, and `check` rejects
anything that decodes but makes no sense for the mission (ids, sizes, non-finite numbers).
"""

from __future__ import annotations

import math

import msgspec

from companion.core.trajectory import Trajectory
from companion.core.wire import MsgpackCodec

PROTOCOL_VERSION = 5
MAX_PLAN = 16


class MessageError(ValueError):
    """A mesh message that must be dropped, with the reason."""


class UavState(msgspec.Struct, frozen=True, array_like=True):
    """What a UAV tells about itself: pose at `stamp`, its planned path (points and the heading at
    each), its task claim, and the safety layer's commitments: the trajectory in force from `stamp`
    on and the proposal it asks to switch to at `stamp + 1` (core.commitment). A UAV whose vehicle
    its companion does not steer (a pilot or the autopilot's own mode flies it) is `steered=False`
    and commits to nothing: the others keep clear of a disk about where it is."""

    uav: int
    stamp: int
    x: float
    y: float
    heading: float
    plan: tuple[tuple[float, float], ...]
    task: int = -1
    task_reward: float = 0.0
    plan_headings: tuple[float, ...] = ()
    committed: Trajectory | None = None
    proposal: Trajectory | None = None
    steered: bool = True


class _Header(msgspec.Struct, frozen=True, tag_field="type", kw_only=True):
    v: int = PROTOCOL_VERSION
    sender: int
    stamp: int
    x: float
    y: float


class StateMsg(_Header, tag="state", frozen=True):
    """The sender's own state (pose, plan, task, commitments), the UAVs whose StateMsg it received at
    its previous step (its first-hand neighbours: what the others need not relay to it), and the
    UAVs it is tethered to (its parents in the tree of links that must hold)."""

    state: UavState
    heard: tuple[int, ...] = ()
    parents: tuple[int, ...] = ()


class CoverageMsg(_Header, tag="coverage", frozen=True):
    """Cells in the sender's FOV at `stamp` (eq. 11 looks) and every target cell it knows of (its camera's
    detections and those it heard of): each step re-announces them all, so a UAV that joins or
    restarts late learns every earlier detection from any neighbour."""

    cells: tuple[int, ...]
    detections: tuple[int, ...] = ()


class BidsMsg(_Header, tag="bids", frozen=True):
    """The sender's rewards R_ij for every task (eq. 15): its bids for the next local auction."""

    rewards: tuple[float, ...]


class ClaimsMsg(_Header, tag="claims", frozen=True):
    """The latest state the sender knows of other UAVs: multi-hop relay of positions and claims."""

    known: tuple[UavState, ...]


Message = StateMsg | CoverageMsg | BidsMsg | ClaimsMsg

_codec: MsgpackCodec[Message] = MsgpackCodec(Message, MessageError, "message")
encode = _codec.encode
decode = _codec.decode  # raises MessageError for anything undecodable


def _finite(*values: float) -> bool:
    return all(math.isfinite(v) for v in values)


def _check_state(s: UavState, n_uavs: int, n_tasks: int) -> None:
    if not 0 <= s.uav < n_uavs:
        raise MessageError(f"state of unknown uav {s.uav}")
    if s.stamp < 0 or not _finite(s.x, s.y, s.heading, s.task_reward):
        raise MessageError(f"state of uav {s.uav}: bad stamp or non-finite value")
    if not -1 <= s.task < n_tasks:
        raise MessageError(f"state of uav {s.uav}: task {s.task} out of range")
    if len(s.plan) > MAX_PLAN or not all(_finite(px, py) for px, py in s.plan):
        raise MessageError(f"state of uav {s.uav}: bad plan")
    if len(s.plan_headings) > len(s.plan) or not _finite(*s.plan_headings):
        raise MessageError(f"state of uav {s.uav}: bad plan headings")
    if not s.steered and (s.committed is not None or s.proposal is not None):
        raise MessageError(f"state of uav {s.uav}: commitments of a vehicle it does not steer")
    for t in (s.committed, s.proposal):
        if t is not None and (
            not 0 <= t.start <= s.stamp + 1
            or t.loiter not in (1, -1)
            or len(t.turns) > MAX_PLAN
            or not _finite(t.x, t.y, t.heading, *t.turns)
            or any(abs(turn) > math.pi for turn in t.turns)
        ):
            raise MessageError(f"state of uav {s.uav}: bad trajectory")


def check(msg: Message, n_uavs: int, n_cells: int, n_tasks: int) -> None:
    """Raise MessageError unless `msg` is a well-formed message of this mission."""
    if msg.v != PROTOCOL_VERSION:
        raise MessageError(f"protocol version {msg.v}, expected {PROTOCOL_VERSION}")
    if not 0 <= msg.sender < n_uavs:
        raise MessageError(f"unknown sender {msg.sender}")
    if msg.stamp < 0 or not _finite(msg.x, msg.y):
        raise MessageError("bad stamp or position")
    if isinstance(msg, StateMsg):
        _check_state(msg.state, n_uavs, n_tasks)
        if msg.state.uav != msg.sender:
            raise MessageError("state of another uav in a state message")
        if msg.state.stamp != msg.stamp:
            raise MessageError("state stamped otherwise than its message")
        if len(msg.heard) >= n_uavs or any(not 0 <= u < n_uavs for u in msg.heard):
            raise MessageError("heard list with unknown uavs")
        if len(msg.parents) > 2 or any(not 0 <= u < n_uavs or u == msg.sender for u in msg.parents):
            raise MessageError("parents list with unknown uavs")
    elif isinstance(msg, CoverageMsg):
        if len(msg.cells) > n_cells or any(not 0 <= c < n_cells for c in msg.cells + msg.detections):
            raise MessageError("cell index out of range")
    elif isinstance(msg, BidsMsg):
        if len(msg.rewards) != n_tasks or not _finite(*msg.rewards) or min(msg.rewards, default=0) < 0:
            raise MessageError("bids must be one finite non-negative reward per task")
    elif isinstance(msg, ClaimsMsg):
        if len(msg.known) > n_uavs:
            raise MessageError("more relayed states than uavs")
        for s in msg.known:
            _check_state(s, n_uavs, n_tasks)
            if s.stamp > msg.stamp:
                raise MessageError("relayed state newer than its message")
