"""The fuzzing campaigns' inputs: Hypothesis strategies that garble valid inputs, and a campaign's tally."""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TypeVar

import msgspec
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import seed as fix_seed
from hypothesis import strategies as st

T = TypeVar("T")


@dataclass
class Campaign:
    """What one campaign fed in and what became of it."""

    name: str
    inputs: int = 0
    accepted: int = 0
    rejected: int = 0
    reasons: Counter[str] = field(default_factory=Counter)
    failures: list[str] = field(default_factory=list)
    seconds: float = 0.0
    notes: dict[str, object] = field(default_factory=dict)

    def reject(self, reason: str) -> None:
        self.rejected += 1
        self.reasons[reason[:60]] += 1


def run_examples(strategy: st.SearchStrategy[T], count: int, seed: int, body: Callable[[T], None]) -> None:
    """`body` on `count` inputs drawn from `strategy` by Hypothesis (reproducible from `seed`)."""
    configured = settings(
        max_examples=count,
        database=None,
        deadline=None,
        suppress_health_check=list(HealthCheck),
        phases=[Phase.generate],
    )
    fix_seed(seed)(configured(given(strategy)(body)))()


def mutations(valid: list[bytes]) -> st.SearchStrategy[bytes]:
    """Valid inputs with bytes flipped, cut, inserted or spliced; and raw bytes."""

    @st.composite
    def mutate(draw: st.DrawFn) -> bytes:
        data = bytearray(draw(st.sampled_from(valid)))
        for _ in range(draw(st.integers(1, 4))):
            op = draw(st.integers(0, 3))
            at = draw(st.integers(0, max(len(data) - 1, 0)))
            if op == 0 and data:
                data[at] = draw(st.integers(0, 255))
            elif op == 1:
                del data[at:]
            elif op == 2:
                data[at:at] = draw(st.binary(max_size=16))
            else:
                data[at:at] = draw(st.sampled_from(valid))[: draw(st.integers(0, 64))]
        return bytes(data)

    return st.one_of(mutate(), st.binary(max_size=256))


JUNK = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-(2**63), 2**64 - 1),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=8),
    st.binary(max_size=8),
    st.lists(st.integers(-5, 3000), max_size=40),
)


def one_field_replaced(valid: list[object]) -> st.SearchStrategy[bytes]:
    """Valid values (as builtins) with one field, at any depth, replaced by a value of any kind."""

    @st.composite
    def replace(draw: st.DrawFn) -> bytes:
        value = draw(st.sampled_from(valid))

        def walk(node: object) -> object:
            if isinstance(node, dict) and node:
                key = draw(st.sampled_from(sorted(node)))
                out = dict(node)
                out[key] = walk(node[key]) if draw(st.booleans()) else draw(JUNK)
                return out
            if isinstance(node, list) and node:
                i = draw(st.integers(0, len(node) - 1))
                items = list(node)
                items[i] = walk(node[i]) if draw(st.booleans()) else draw(JUNK)
                return items
            return draw(JUNK)

        return msgspec.msgpack.encode(walk(value))

    return replace()
