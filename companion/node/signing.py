"""End-to-end signatures on the mesh: which UAV said what, however many hops it travelled.

Each bundle travels in an `Envelope`: the encoded bundle, its sender's Ed25519 signature over it,
and one originator signature per UAV state it carries (the sender's own first, then every relayed
one), over texts naming the mission's key space and the run. Signatures are kept (bounded) so that
a relayed state is checked once and can be relayed on with its originator's signature; a state
whose signature is not held or does not check is not relayed. See docs/reliability.md,
"Signatures: who said what, over any number of hops".
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence

import msgspec
from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey, Ed25519PublicKey

from companion.contracts.wire import MsgpackCodec
from companion.core.messages import ClaimsMsg, Message, MessageError, StateMsg, UavState

SIGNATURE_BYTES = 64
KEPT_PER_UAV = 16  # checked state signatures kept per UAV (a relay needs only the latest few)
RELOAD_S = 5.0  # a signature that does not check reads the accepted keys again at most this often
PublicKeys = Sequence[Sequence[Ed25519PublicKey]]  # per UAV: the keys accepted for it


class Unauthenticated(MessageError):
    """A bundle without a valid signature of the sender it names."""


class Forged(MessageError):
    """A bundle carrying a state whose originator's signature does not check."""


class Envelope(msgspec.Struct, frozen=True, array_like=True):
    """What goes on the wire in a secured mesh: a bundle with its signatures.

    It holds the encoded bundle, its sender's signature and the originators' signatures of the
    states in it. An insecure mesh sends the bare bundle.
    """

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

    `public[i]` are the keys accepted for UAV i; `base` the mission's key space and `run` the run
    identity (both bound into every signed text). `reload` gives the accepted keys as they are now
    (a key rotated since): called when a signature does not check, at most once per RELOAD_S.
    A listener without a key of its own (the live view) passes `signing=None`: it only checks.
    A sender's signature of its own state is kept unchecked (the bundle's signature already
    vouches for what the sender says about itself) and checked only if the state is to be relayed.
    """

    def __init__(
        self,
        public: PublicKeys,
        base: str,
        signing: Ed25519PrivateKey | None = None,
        run: str = "",
        reload: Callable[[], PublicKeys] | None = None,
    ) -> None:
        self.public = tuple(tuple(keys) for keys in public)
        self.signing, self._reload = signing, reload
        bound = base.encode() + b"\0" + run.encode() + b"\0"
        self._bundle_domain = b"uavsearch bundle\0" + bound
        self._state_domain = b"uavsearch state\0" + bound
        self._next_reload = -float("inf")
        self._lock = threading.Lock()
        # per UAV: state bytes -> (its signature, checked)
        self._sigs: list[dict[bytes, tuple[bytes, bool]]] = [{} for _ in self.public]

    # -- sending -------------------------------------------------------------------------------
    def relayable(self, messages: list[Message]) -> list[Message]:
        """`messages` without the relayed states whose originator's signature is missing or bad.

        A state is dropped when we do not hold its originator's signature, or the signature does
        not check.
        """
        out: list[Message] = []
        for msg in messages:
            if isinstance(msg, ClaimsMsg):
                known = tuple(s for s in msg.known if self._relay_sig(s, _state_bytes(s)) is not None)
                if not known:
                    continue
                if len(known) != len(msg.known):
                    msg = msgspec.structs.replace(msg, known=known)
            out.append(msg)
        return out

    def seal(self, body: bytes, messages: Sequence[Message]) -> bytes:
        """The envelope of an encoded bundle: signed, with the originators' state signatures.

        Call `relayable` first: every relayed state must have a checked signature held here.
        """
        if self.signing is None:
            raise ValueError("a listener without a signing key cannot send")
        sigs: list[bytes] = []
        for state in carried_states(messages):
            data = _state_bytes(state)
            held = self._held(state.uav, data)
            if held is None:  # our own state: sign it, and keep it like any other
                held = (self.signing.sign(self._state_domain + data), True)
                self._keep(state.uav, data, held)
            sigs.append(held[0])
        return encode_envelope(Envelope(body, self.signing.sign(self._bundle_domain + body), tuple(sigs)))

    # -- receiving -----------------------------------------------------------------------------
    def check(self, envelope: Envelope, sender: int, messages: Sequence[Message]) -> None:
        """Check an envelope's signatures: Unauthenticated or Forged if one fails.

        Raises Unauthenticated unless `sender` signed the envelope's body, Forged unless every
        carried state about another UAV is signed by that UAV. Keeps the states' signatures for
        relaying (the sender's own unchecked).
        """
        if not self._checks(sender, envelope.sig, self._bundle_domain + envelope.body):
            raise Unauthenticated(f"bundle not signed by uav {sender}")
        states = carried_states(messages)
        if len(states) != len(envelope.state_sigs):
            raise Forged(f"{len(states)} states, {len(envelope.state_sigs)} signatures")
        for state, sig in zip(states, envelope.state_sigs, strict=True):
            data = _state_bytes(state)
            held = self._held(state.uav, data)
            if held is not None and held[0] == sig and (held[1] or state.uav == sender):
                continue
            if state.uav == sender:
                self._keep(state.uav, data, (sig, False))
                continue
            if not self._verify(state.uav, data, sig):
                raise Forged(f"state of uav {state.uav} (stamp {state.stamp}) not signed by it")
            self._keep(state.uav, data, (sig, True))

    # -- held signatures ---------------------------------------------------------------------------
    def _relay_sig(self, state: UavState, data: bytes) -> bytes | None:
        """The checked signature of a state to relay (checking it now if need be), else None."""
        held = self._held(state.uav, data)
        if held is None:
            return None
        if not held[1]:
            if not self._verify(state.uav, data, held[0]):
                with self._lock:
                    self._sigs[state.uav].pop(data, None)
                return None
            self._keep(state.uav, data, (held[0], True))
        return held[0]

    def _verify(self, uav: int, data: bytes, sig: bytes) -> bool:
        return self._checks(uav, sig, self._state_domain + data)

    def _checks(self, uav: int, sig: bytes, text: bytes) -> bool:
        """Whether `sig` is UAV `uav`'s signature of `text` under a key accepted for it.

        Before saying no it reads the accepted keys again, rate-limited.
        """
        if _signed_by(self.public[uav], sig, text):
            return True
        with self._lock:
            now = time.monotonic()
            if self._reload is None or now < self._next_reload:
                return False
            self._next_reload = now + RELOAD_S
        try:
            public = tuple(tuple(keys) for keys in self._reload())
        except (OSError, ValueError):  # a key file being rewritten: the keys held stay
            return False
        if len(public) != len(self.public):
            return False
        self.public = public
        return _signed_by(public[uav], sig, text)

    def _held(self, uav: int, data: bytes) -> tuple[bytes, bool] | None:
        with self._lock:
            return self._sigs[uav].get(data)

    def _keep(self, uav: int, data: bytes, entry: tuple[bytes, bool]) -> None:
        with self._lock:
            held = self._sigs[uav]
            held[data] = entry
            if len(held) > KEPT_PER_UAV:
                del held[next(iter(held))]


def _signed_by(keys: Sequence[Ed25519PublicKey], sig: bytes, text: bytes) -> bool:
    for key in keys:
        try:
            key.verify(sig, text)
        except InvalidSignature:
            continue
        return True
    return False
