"""The proof a message carries in its Zenoh attachment, readable from any language.

The payload stays as it is (MessagePack). The attachment is a MessagePack map with

``kid``  8 bytes: the signer's key id (first 8 bytes of SHA-256 of its raw public key)
``sig``  64 bytes: Ed25519 over ``b"ovis-proof-v1\\0" + key_expr + b"\\0" + payload``

so a proof cannot be moved to another key expression (another arena or topic) nor to
other bytes. Other keys of the map are ignored (``ovis replay`` puts its replay mark in
the attachment too). What it does not prove: that a message is new (a recorded genuine
message replays with its proof): a :class:`Verifier` also refuses a proven message that
does not come after the last one on its key (:mod:`.order`); calibrations carry their
store's identity and version for that (:mod:`ovis.common.pipeline.following`).
"""

from __future__ import annotations

import time
from typing import Annotated

import msgspec
from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

from ovis.common.trust.keys import PublicKeyFile, key_id
from ovis.common.trust.order import ReplayGuard

__all__ = ["DOMAIN", "Proof", "Signer", "Verifier", "signed_bytes"]

#: What every signed message starts with (a signature made for something else is never
#: taken for one of these).
DOMAIN = b"ovis-proof-v1\x00"


class Proof(msgspec.Struct, kw_only=True, forbid_unknown_fields=False):
    """The attachment's proof: key id and signature."""

    kid: Annotated[bytes, msgspec.Meta(min_length=8, max_length=8)]
    sig: Annotated[bytes, msgspec.Meta(min_length=64, max_length=64)]


_decoder = msgspec.msgpack.Decoder(Proof)


def signed_bytes(key_expr: str, payload: bytes) -> bytes:
    """What is signed: the domain, the key expression and the exact payload bytes."""
    return DOMAIN + key_expr.encode() + b"\x00" + payload


class Signer:
    """Makes the attachment that proves a payload published on a key expression."""

    def __init__(self, key: Ed25519PrivateKey) -> None:
        self._key = key
        self.kid = key_id(key.public_key())

    def attachment(self, key_expr: str, payload: bytes) -> bytes:
        sig = self._key.sign(signed_bytes(key_expr, payload))
        return msgspec.msgpack.encode(Proof(kid=self.kid, sig=sig))


class Verifier:
    """Checks the proof of a received message against one trusted public key file, and
    that a proven message is not a replay (:class:`~.order.ReplayGuard`: each consumer
    has its own, as it has its own last message per key)."""

    def __init__(self, trusted: PublicKeyFile) -> None:
        self.trusted = trusted
        self.order = ReplayGuard()

    def problem(self, key_expr: str, payload: bytes, attachment: bytes | None) -> str | None:
        """Why the message is not proven to come from the key's holder now (no proof, a
        bad one, or a replay of a genuine one), or None: it is taken."""
        if why := self._unsigned(key_expr, payload, attachment):
            return why
        return self.order.problem(key_expr, payload, time.time_ns())

    def _unsigned(self, key_expr: str, payload: bytes, attachment: bytes | None) -> str | None:
        """Why the message is not signed by the key's holder, or None."""
        key = self.trusted.key()
        if key is None:
            return f"cannot verify: {self.trusted.problem}"
        if not attachment:
            return "no proof of origin"
        try:
            proof = _decoder.decode(attachment)
        except (msgspec.DecodeError, msgspec.ValidationError) as exc:
            return f"not a proof of origin: {exc}"
        if proof.kid != key_id(key):
            return f"signed by key {proof.kid.hex()}, not the trusted {key_id(key).hex()}"
        try:
            key.verify(proof.sig, signed_bytes(key_expr, payload))
        except InvalidSignature:
            return f"bad signature for {key_expr} (payload or key expression changed)"
        return None
