"""End-to-end signatures on the mesh: which UAV said what, however many hops it travelled.

Each bundle travels in an `Envelope`: the encoded bundle, its sender's Ed25519 signature over it,
and one originator signature per UAV state it carries (the sender's own `StateMsg` state first,
then every state relayed in a `ClaimsMsg`, in order). A receiver checks the bundle's signature with
the public key of the sender it names, and every state's with the key of the UAV the state is
about, so a state relayed over any number of UAVs still proves its origin, and a member cannot put
words in another's mouth. The signed texts name the mission's key space, so nothing signed for one
mission is accepted by another. Detections and bids are first-hand only: the bundle's signature
covers them.

Signatures a receiver has checked are kept (bounded) so that a state relayed by several neighbours
is verified once, and so that this UAV can relay it with its originator's signature. A state whose
signature it does not hold (none ever arrived, or it came back from a restart journal) is not
relayed. See docs/reliability.md.
"""

from __future__ import annotations

import threading
from collections.abc import Sequence

import msgspec
from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey, Ed25519PublicKey

from companion.core.messages import ClaimsMsg, Message, MessageError, StateMsg, UavState
from companion.core.wire import MsgpackCodec

SIGNATURE_BYTES = 64
KEPT_PER_UAV = 16  # checked state signatures kept per UAV (a relay needs only the latest few)


class Unauthenticated(MessageError):
    """A bundle without a valid signature of the sender it names."""


class Forged(MessageError):
    """A bundle carrying a state whose originator's signature does not check."""


class Envelope(msgspec.Struct, frozen=True, array_like=True):
    """What goes on the wire in a secured mesh: the encoded bundle, its sender's signature and the
    originators' signatures of the states in it (an insecure mesh sends the bare bundle)."""

    body: bytes
    sig: bytes
    state_sigs: tuple[bytes, ...]


_codec: MsgpackCodec[Envelope] = MsgpackCodec(Envelope, MessageError, "envelope")
encode_envelope = _codec.encode
decode_envelope = _codec.decode
_state_bytes = msgspec.msgpack.Encoder().encode


def carried_states(messages: Sequence[Message]) -> list[UavState]:
    """The UAV states in a bundle's messages, in the order their signatures travel."""
    states: list[UavState] = []
    for msg in messages:
        if isinstance(msg, StateMsg):
            states.append(msg.state)
        elif isinstance(msg, ClaimsMsg):
            states.extend(msg.known)
    return states


class Authenticator:
    """Signs this UAV's bundles (with `signing`, its private key) and checks everyone's.

    `public[i]` is UAV i's key; `base` the mission's key space (bound into every signed text).
    A listener without a key of its own (the live view) passes `signing=None`: it only checks.
    """

    def __init__(
        self, public: Sequence[Ed25519PublicKey], base: str, signing: Ed25519PrivateKey | None = None
    ) -> None:
        self.public, self.signing = tuple(public), signing
        self._bundle_domain = b"uavsearch bundle\0" + base.encode() + b"\0"
        self._state_domain = b"uavsearch state\0" + base.encode() + b"\0"
        self._lock = threading.Lock()
        self._sigs: list[dict[bytes, bytes]] = [{} for _ in self.public]  # per UAV: state bytes -> sig

    # -- sending -------------------------------------------------------------------------------
    def relayable(self, messages: list[Message]) -> list[Message]:
        """`messages` without the relayed states whose originator's signature we do not hold."""
        out: list[Message] = []
        for msg in messages:
            if isinstance(msg, ClaimsMsg):
                known = tuple(s for s in msg.known if self._held(s, _state_bytes(s)) is not None)
                if not known:
                    continue
                if len(known) != len(msg.known):
                    msg = msgspec.structs.replace(msg, known=known)
            out.append(msg)
        return out

    def seal(self, body: bytes, messages: Sequence[Message]) -> bytes:
        """The envelope of an encoded bundle: signed, with the originators' state signatures.

        Call `relayable` first: every relayed state must have a signature held here.
        """
        if self.signing is None:
            raise ValueError("a listener without a signing key cannot send")
        sigs: list[bytes] = []
        for state in carried_states(messages):
            data = _state_bytes(state)
            sig = self._held(state, data)
            if sig is None:  # our own state: sign it, and keep it like any other
                sig = self.signing.sign(self._state_domain + data)
                self._keep(state.uav, data, sig)
            sigs.append(sig)
        return encode_envelope(Envelope(body, self.signing.sign(self._bundle_domain + body), tuple(sigs)))

    # -- receiving -----------------------------------------------------------------------------
    def check(self, envelope: Envelope, sender: int, messages: Sequence[Message]) -> None:
        """Raise Unauthenticated unless `sender` signed the envelope's body, Forged unless every
        carried state is signed by its own UAV; keep the states' signatures for relaying."""
        try:
            self.public[sender].verify(envelope.sig, self._bundle_domain + envelope.body)
        except InvalidSignature:
            raise Unauthenticated(f"bundle not signed by uav {sender}") from None
        states = carried_states(messages)
        if len(states) != len(envelope.state_sigs):
            raise Forged(f"{len(states)} states, {len(envelope.state_sigs)} signatures")
        for state, sig in zip(states, envelope.state_sigs, strict=True):
            data = _state_bytes(state)
            if self._held(state, data) == sig:
                continue
            try:
                self.public[state.uav].verify(sig, self._state_domain + data)
            except InvalidSignature:
                raise Forged(f"state of uav {state.uav} (stamp {state.stamp}) not signed by it") from None
            self._keep(state.uav, data, sig)

    def _held(self, state: UavState, data: bytes) -> bytes | None:
        with self._lock:
            return self._sigs[state.uav].get(data)

    def _keep(self, uav: int, data: bytes, sig: bytes) -> None:
        with self._lock:
            held = self._sigs[uav]
            held[data] = sig
            if len(held) > KEPT_PER_UAV:
                del held[next(iter(held))]
