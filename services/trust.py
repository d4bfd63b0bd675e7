"""The proof of origin on the bus (:mod:`ovis.common.trust`): a stage's signer, a
consumer's verifier of a role's messages, and queries that ask for every answer."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import zenoh

from ovis.common.config import OvisConfig
from ovis.common.trust.keys import (
    PublicKeyFile,
    load_or_create_private,
    private_key_path,
    public_key_path,
)
from ovis.common.trust.proof import Signer, Verifier

__all__ = ["attachment_of", "every_reply", "signer_for", "unproven", "verifier_for"]


def signer_for(cfg: OvisConfig, role: str) -> Signer:
    """The signer of ``role`` with its private key (made on first start; KeyFileError
    saying why when it cannot be read or written)."""
    return Signer(load_or_create_private(private_key_path(cfg, role)))


def verifier_for(cfg: OvisConfig, role: str, trust: Path | None = None) -> Verifier:
    """A verifier of ``role``'s messages: with the public key file ``trust``, else the one
    the configuration names."""
    return Verifier(PublicKeyFile(trust or public_key_path(cfg, role)))


def attachment_of(sample: zenoh.Sample) -> bytes | None:
    attachment = sample.attachment
    return None if attachment is None else attachment.to_bytes()


def unproven(verifier: Verifier, sample: zenoh.Sample, payload: bytes) -> str | None:
    """Why a received sample is not proven by ``verifier``'s key, or None."""
    return verifier.problem(str(sample.key_expr), payload, attachment_of(sample))


def every_reply(session: zenoh.Session, key: str, **options: Any) -> Iterator[zenoh.Reply]:
    """A query delivered to every queryable of ``key``, each of their answers kept (no
    consolidation): a second answer (a forger's) cannot hide the genuine one."""
    yield from session.get(
        key,
        target=zenoh.QueryTarget.ALL,
        consolidation=zenoh.ConsolidationMode.NONE,
        **options,
    )
