"""Bundles without a network: wire round trip and validation."""

from __future__ import annotations

import math

import msgspec
import pytest
from mesh_helpers import N_CELLS, N_TASKS, outbox

from companion.core.messages import PROTOCOL_VERSION, ClaimsMsg, CoverageMsg, MessageError, UavState
from companion.node.mesh import MAX_BUNDLE_MESSAGES, Bundle, check_bundle, decode_bundle, encode_bundle


def _bundle(**changes: object) -> Bundle:
    b = Bundle(sender=1, stamp=7, x=10.5, y=-3.25, messages=tuple(outbox(1, 7, 10.5, -3.25)))
    return msgspec.structs.replace(b, **changes)


def test_round_trip_keeps_every_message_exactly() -> None:
    known = (UavState(uav=2, stamp=6, x=0.1, y=0.2, heading=3.0, plan=(), task=1, task_reward=0.5),)
    extra = ClaimsMsg(sender=1, stamp=7, x=10.5, y=-3.25, known=known)
    bundle = _bundle(messages=(*_bundle().messages, extra))
    data = encode_bundle(bundle)
    assert decode_bundle(data) == bundle
    check_bundle(decode_bundle(data), 4, N_CELLS, N_TASKS)


def test_empty_bundle_is_valid() -> None:
    check_bundle(decode_bundle(encode_bundle(_bundle(messages=()))), 4, N_CELLS, N_TASKS)


@pytest.mark.parametrize(
    ("changes", "reason"),
    [
        ({"v": PROTOCOL_VERSION + 1}, "version"),
        ({"sender": 4}, "sender"),
        ({"sender": -1}, "sender"),
        ({"stamp": -1}, "stamp"),
        ({"x": math.nan}, "position"),
        ({"y": math.inf}, "position"),
        ({"stamp": 8}, "header"),  # messages stamped 7
        ({"x": 10.0}, "header"),
        ({"messages": (CoverageMsg(sender=1, stamp=7, x=10.5, y=-3.25, cells=(N_CELLS,)),)}, "cell"),
    ],
)
def test_check_rejects(changes: dict, reason: str) -> None:
    with pytest.raises(MessageError, match=reason):
        check_bundle(_bundle(**changes), 4, N_CELLS, N_TASKS)


@pytest.mark.parametrize(
    "data",
    [
        b"",
        b"\xc1garbage",
        msgspec.msgpack.encode({"v": 1, "sender": "one"}),
        msgspec.msgpack.encode([1, 2, 3]),
        encode_bundle(_bundle(messages=(_bundle().messages[0],) * (MAX_BUNDLE_MESSAGES + 1))),
    ],
)
def test_decode_rejects_malformed_bytes(data: bytes) -> None:
    with pytest.raises(MessageError, match="undecodable"):
        decode_bundle(data)
