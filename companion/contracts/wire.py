"""Msgpack codecs for the typed messages that cross process boundaries (mesh, camera)."""

from __future__ import annotations

from typing import Any, Generic, TypeVar

import msgspec

T = TypeVar("T")


class MsgpackCodec(Generic[T]):
    """Encodes values of one msgspec type and decodes bytes back, raising `error` on bad input."""

    def __init__(self, kind: Any, error: type[ValueError], what: str) -> None:
        self._encoder = msgspec.msgpack.Encoder()
        self._decoder: msgspec.msgpack.Decoder[T] = msgspec.msgpack.Decoder(kind)
        self._error, self._what = error, what

    def encode(self, value: T) -> bytes:
        return self._encoder.encode(value)

    def decode(self, data: bytes) -> T:
        """Wire bytes to a value; raises the codec's error for anything undecodable."""
        try:
            return self._decoder.decode(data)
        except (msgspec.DecodeError, msgspec.ValidationError) as exc:
            raise self._error(f"undecodable {self._what}: {exc}") from None
