"""Versioned mesh messages: msgpack round trip, `check` of malformed messages, garbage bytes."""

from __future__ import annotations

import math

import msgspec
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.core.messages import (
    PROTOCOL_VERSION,
    BidsMsg,
    ClaimsMsg,
    CoverageMsg,
    Message,
    MessageError,
    StateMsg,
    UavState,
    check,
    decode,
    encode,
)

N_UAVS, N_CELLS, N_TASKS = 4, 100, 5
HEAD = {"sender": 1, "stamp": 7, "x": 10.0, "y": -20.0}

finite = st.floats(-1e6, 1e6, allow_nan=False)
uav = st.integers(0, N_UAVS - 1)
stamp = st.integers(0, 10**6)
states = st.builds(
    UavState,
    uav=uav,
    stamp=stamp,
    x=finite,
    y=finite,
    heading=st.floats(-math.pi, math.pi),
    plan=st.lists(st.tuples(finite, finite), max_size=6).map(tuple),
    task=st.integers(-1, N_TASKS - 1),
    task_reward=st.floats(0, 100),
)
header = {"sender": uav, "stamp": stamp, "x": finite, "y": finite}
messages = st.one_of(
    states.flatmap(
        lambda s: st.builds(
            StateMsg, sender=st.just(s.uav), stamp=st.just(s.stamp), x=finite, y=finite, state=st.just(s)
        )
    ),
    st.builds(
        CoverageMsg,
        **header,
        cells=st.lists(st.integers(0, N_CELLS - 1), max_size=13).map(tuple),
        detections=st.lists(st.integers(0, N_CELLS - 1), max_size=3).map(tuple),
    ),
    st.builds(
        BidsMsg, **header, rewards=st.lists(st.floats(0, 10), min_size=N_TASKS, max_size=N_TASKS).map(tuple)
    ),
    st.builds(ClaimsMsg, **header, known=st.lists(states, max_size=N_UAVS).map(tuple)).map(
        lambda m: msgspec.structs.replace(  # relayed states are never newer than their message
            m, known=tuple(msgspec.structs.replace(s, stamp=min(s.stamp, m.stamp)) for s in m.known)
        )
    ),
)


@settings(max_examples=50, deadline=None)
@given(messages)
def test_round_trip_and_well_formed_messages_pass_check(msg: Message) -> None:
    data = encode(msg)
    assert isinstance(data, bytes)
    back = decode(data)
    assert back == msg and type(back) is type(msg)
    check(back, N_UAVS, N_CELLS, N_TASKS)


@settings(max_examples=50, deadline=None)
@given(st.binary(max_size=200))
def test_decode_garbage_raises_message_error(data: bytes) -> None:
    try:
        msg = decode(data)
    except MessageError:
        return
    # the rare byte string that is a valid message must be one of the message types
    assert isinstance(msg, StateMsg | CoverageMsg | BidsMsg | ClaimsMsg)


@pytest.mark.parametrize(
    "data",
    [
        b"",
        b"\xc1",  # a byte msgpack never uses
        msgspec.msgpack.encode({"type": "bogus", "sender": 0, "stamp": 0, "x": 0.0, "y": 0.0}),
        msgspec.msgpack.encode({"type": "bids", "sender": 0, "stamp": 0, "x": "a", "y": 0.0, "rewards": []}),
        msgspec.msgpack.encode([1, 2, 3]),
    ],
)
def test_decode_specific_garbage(data: bytes) -> None:
    with pytest.raises(MessageError):
        decode(data)


def state(**kw: object) -> UavState:
    base = {"uav": 1, "stamp": 7, "x": 0.0, "y": 0.0, "heading": 0.0, "plan": ((40.0, 0.0),), "task": 2}
    return UavState(**{**base, **kw})  # type: ignore[arg-type]


def test_check_accepts_well_formed() -> None:
    check(StateMsg(**HEAD, state=state()), N_UAVS, N_CELLS, N_TASKS)
    check(CoverageMsg(**HEAD, cells=(0, 99), detections=(5,)), N_UAVS, N_CELLS, N_TASKS)
    check(BidsMsg(**HEAD, rewards=(0.0,) * N_TASKS), N_UAVS, N_CELLS, N_TASKS)
    check(ClaimsMsg(**HEAD, known=(state(uav=0), state(uav=3))), N_UAVS, N_CELLS, N_TASKS)


@pytest.mark.parametrize(
    "msg",
    [
        StateMsg(**HEAD, v=PROTOCOL_VERSION + 1, state=state()),  # wrong version
        CoverageMsg(**{**HEAD, "sender": 4}, cells=()),  # unknown sender
        CoverageMsg(**{**HEAD, "sender": -1}, cells=()),
        CoverageMsg(**{**HEAD, "stamp": -1}, cells=()),
        CoverageMsg(**{**HEAD, "x": math.nan}, cells=()),  # NaN position
        CoverageMsg(**{**HEAD, "y": math.inf}, cells=()),
        StateMsg(**HEAD, state=state(x=math.nan)),  # NaN in the state
        StateMsg(**HEAD, state=state(uav=2)),  # state of another UAV
        StateMsg(**HEAD, state=state(task=N_TASKS + N_CELLS)),  # beyond the last confirmation task
        StateMsg(**HEAD, state=state(task=-2)),
        StateMsg(**HEAD, state=state(plan=((math.nan, 0.0),))),
        StateMsg(**HEAD, state=state(plan=((0.0, 0.0),) * 17)),  # plan too long
        CoverageMsg(**HEAD, cells=(0, N_CELLS)),  # out-of-range cell
        CoverageMsg(**HEAD, cells=(-1,)),
        CoverageMsg(**HEAD, cells=(), detections=(N_CELLS,)),
        CoverageMsg(**HEAD, cells=(0, 1), evidence=(1.0,)),  # evidence not one per cell
        CoverageMsg(**HEAD, cells=(0,), evidence=(math.nan,)),
        CoverageMsg(**HEAD, cells=(), records=(0, 1), record_values=(1.0,)),  # not a triple
        CoverageMsg(**HEAD, cells=(), records=(4, 1, 0), record_values=(1.0,)),  # unknown source
        CoverageMsg(**HEAD, cells=(), records=(0, N_CELLS, 0), record_values=(1.0,)),
        CoverageMsg(**HEAD, cells=(), records=(0, 1, HEAD["stamp"] + 1), record_values=(1.0,)),  # future
        CoverageMsg(**HEAD, cells=(), records=(0, 1, 0), record_values=(math.inf,)),
        CoverageMsg(**HEAD, cells=(), records=(0, 1, 0) * 1025, record_values=(1.0,) * 1025),  # too many
        BidsMsg(**HEAD, rewards=(1.0,) * N_TASKS, confirm=(1, 2), confirm_rewards=(1.0,)),
        BidsMsg(**HEAD, rewards=(1.0,) * N_TASKS, confirm=(N_CELLS,), confirm_rewards=(1.0,)),
        BidsMsg(**HEAD, rewards=(1.0,) * N_TASKS, confirm=(1,), confirm_rewards=(-1.0,)),
        BidsMsg(**HEAD, rewards=(1.0,) * (N_TASKS - 1)),  # wrong bid length
        BidsMsg(**HEAD, rewards=(1.0,) * (N_TASKS + 1)),
        BidsMsg(**HEAD, rewards=(1.0, math.nan, 1.0, 1.0, 1.0)),
        BidsMsg(**HEAD, rewards=(1.0, -1.0, 1.0, 1.0, 1.0)),
        ClaimsMsg(**HEAD, known=(state(uav=9),)),  # relayed state of an unknown UAV
        ClaimsMsg(**HEAD, known=(state(uav=0, task=N_TASKS + N_CELLS),)),
        ClaimsMsg(**HEAD, known=tuple(state(uav=i % N_UAVS) for i in range(N_UAVS + 1))),
    ],
)
def test_check_rejects_malformed(msg: Message) -> None:
    with pytest.raises(MessageError):
        check(msg, N_UAVS, N_CELLS, N_TASKS)


def test_malformed_survives_the_wire_and_is_caught_by_check() -> None:
    # a decodable message from a future protocol version is rejected after decoding
    back = decode(encode(BidsMsg(**HEAD, v=PROTOCOL_VERSION + 1, rewards=(1.0,) * N_TASKS)))
    with pytest.raises(MessageError, match="version"):
        check(back, N_UAVS, N_CELLS, N_TASKS)
