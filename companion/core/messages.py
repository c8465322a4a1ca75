"""Versioned mesh messages between agents: state, coverage/detections, bids and claims.

Every message carries the protocol version, its sender's id, the step it was produced at (its
sequence number) and the sender's position at that step (for range gating on receipt). Messages
are immutable msgspec structs; `encode`/`decode` give the msgpack wire form, and `check` rejects
anything that decodes but makes no sense for the mission (ids, sizes, non-finite numbers).
"""

from __future__ import annotations

import math

import msgspec

from companion.contracts.wire import MsgpackCodec
from companion.core.trajectory import Trajectory

PROTOCOL_VERSION = 6
MAX_RECORDS = 1024  # evidence records one coverage message relays (`Belief.records`)
MAX_EVIDENCE = 1e9  # |cumulative log-odds evidence| of a record
MAX_PLAN = 16


class MessageError(ValueError):
    """A mesh message that must be dropped, with the reason."""


class UavState(msgspec.Struct, frozen=True, array_like=True):
    """What a UAV tells about itself: pose, planned path, task claim and safety commitments.

    The pose is at `stamp`; the planned path is its points and the heading at each; the safety
    layer's commitments are the trajectory in force from `stamp` on and the proposal it asks to
    switch to at `stamp + 1` (core.commitment). A UAV whose vehicle its companion does not steer (a
    pilot or the autopilot's own mode flies it) is `steered=False` and commits to nothing: the others
    keep clear of a disk about where it is.
    """

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


class StateMsg(_Header, frozen=True, tag="state"):
    """The sender's own state, the UAVs it heard first-hand, and the UAVs it is tethered to.

    `state`: its pose, plan, task and commitments. `heard`: the UAVs whose StateMsg it received at its
    previous step (its first-hand neighbours: what the others need not relay to it). `parents`: the
    UAVs it is tethered to (its parents in the tree of links that must hold).
    """

    state: UavState
    heard: tuple[int, ...] = ()
    parents: tuple[int, ...] = ()


class CoverageMsg(_Header, frozen=True, tag="coverage"):
    """The sender's looks at `stamp` (eq. 11), its evidence, and what it knows of the targets.

    `cells`: its FOV at `stamp`; `evidence`: its cumulative log-odds evidence at each of them after
    those looks (`core.belief`). `records`/`record_values`: every evidence record it holds at the
    cells of interest (confirmed or candidate), as (source, cell, stamp) triples and values, so
    that a UAV that joins, restarts or was out of range learns every detection from any
    neighbour. `detections`: the cells it holds confirmed (for ground stations and views).
    """

    cells: tuple[int, ...]
    detections: tuple[int, ...] = ()
    evidence: tuple[float, ...] = ()
    records: tuple[int, ...] = ()
    record_values: tuple[float, ...] = ()


class BidsMsg(_Header, frozen=True, tag="bids"):
    """The sender's rewards R_ij for every task (eq. 15): its bids for the next local auction.

    `confirm`/`confirm_rewards`: its bids for the confirmation tasks of the candidate cells it
    knows of (docs/algorithm.md, "Imperfect sensing")."""

    rewards: tuple[float, ...]
    confirm: tuple[int, ...] = ()
    confirm_rewards: tuple[float, ...] = ()


class ClaimsMsg(_Header, frozen=True, tag="claims"):
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


def _check_coverage(msg: CoverageMsg, n_uavs: int, n_cells: int) -> None:
    if len(msg.cells) > n_cells or any(not 0 <= c < n_cells for c in msg.cells + msg.detections):
        raise MessageError("cell index out of range")
    if msg.evidence and len(msg.evidence) != len(msg.cells):
        raise MessageError("evidence must be one value per cell looked at")
    records, values = msg.records, msg.record_values
    if len(values) > MAX_RECORDS or len(records) != 3 * len(values):
        raise MessageError(f"records: (source, cell, stamp) triples, one per value, at most {MAX_RECORDS}")
    if any(not -MAX_EVIDENCE <= v <= MAX_EVIDENCE for v in msg.evidence + values):  # also NaN
        raise MessageError("evidence must be finite")
    for i in range(0, len(records), 3):
        u, c, s = records[i : i + 3]
        if not (0 <= u < n_uavs and 0 <= c < n_cells and 0 <= s <= msg.stamp):
            raise MessageError(f"record ({u}, {c}, {s}): unknown uav or cell, or stamped after its message")


def check(msg: Message, n_uavs: int, n_cells: int, n_tasks: int) -> None:
    """Raise MessageError unless `msg` is a well-formed message of this mission."""
    if msg.v != PROTOCOL_VERSION:
        raise MessageError(f"protocol version {msg.v}, expected {PROTOCOL_VERSION}")
    if not 0 <= msg.sender < n_uavs:
        raise MessageError(f"unknown sender {msg.sender}")
    if msg.stamp < 0 or not _finite(msg.x, msg.y):
        raise MessageError("bad stamp or position")
    tasks = n_tasks + n_cells if n_tasks else 0  # a cell's confirmation task is n_tasks + cell
    if isinstance(msg, StateMsg):
        _check_state(msg.state, n_uavs, tasks)
        if msg.state.uav != msg.sender:
            raise MessageError("state of another uav in a state message")
        if msg.state.stamp != msg.stamp:
            raise MessageError("state stamped otherwise than its message")
        if len(msg.heard) >= n_uavs or any(not 0 <= u < n_uavs for u in msg.heard):
            raise MessageError("heard list with unknown uavs")
        if len(msg.parents) > 2 or any(not 0 <= u < n_uavs or u == msg.sender for u in msg.parents):
            raise MessageError("parents list with unknown uavs")
    elif isinstance(msg, CoverageMsg):
        _check_coverage(msg, n_uavs, n_cells)
    elif isinstance(msg, BidsMsg):
        if len(msg.rewards) != n_tasks or not _finite(*msg.rewards) or min(msg.rewards, default=0) < 0:
            raise MessageError("bids must be one finite non-negative reward per task")
        if (
            len(msg.confirm) != len(msg.confirm_rewards)
            or len(msg.confirm) > n_cells
            or any(not 0 <= c < n_cells for c in msg.confirm)
            or not _finite(*msg.confirm_rewards)
            or min(msg.confirm_rewards, default=0) < 0
        ):
            raise MessageError("confirmation bids must be one finite non-negative reward per known cell")
    elif isinstance(msg, ClaimsMsg):
        if len(msg.known) > n_uavs:
            raise MessageError("more relayed states than uavs")
        for s in msg.known:
            _check_state(s, n_uavs, tasks)
            if s.stamp > msg.stamp:
                raise MessageError("relayed state newer than its message")
