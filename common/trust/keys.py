"""Key files of the proof of origin: a stage's private key (made on first use, mode
0600, kept across restarts) and the public keys the others trust, as PEM files that any
Ed25519 library reads (``openssl pkey -pubin -in calibrator.pub -text``).

Where they are: ``[trust] keys_dir`` (default ``<state_dir>/keys``) holds
``<role>.key`` and ``<role>.pub``; ``[trust] calibrator_public``, ``pose_public``,
``fusion_public`` and ``planner_public`` name a public key copied from another host
instead (docs/trust.md).
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import tempfile
import threading
import time
from pathlib import Path

from cryptography.exceptions import UnsupportedAlgorithm
from cryptography.hazmat.primitives import serialization
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey, Ed25519PublicKey

from ovis.common.atomic import write_atomic
from ovis.common.config import OvisConfig

__all__ = [
    "ROLES",
    "KeyFileError",
    "PublicKeyFile",
    "key_id",
    "keys_dir",
    "load_or_create_private",
    "load_public",
    "private_key_path",
    "public_key_path",
    "public_pem",
]

#: The stages whose word counts: the calibrator (calibrations), the pose stage
#: (obstacles, robots, the stream's health), fusion (the several cameras' world) and
#: the planner (the robots' velocity commands).
ROLES = ("calibrator", "pose", "fusion", "planner")
#: Seconds between two reads of a public key file that is missing or bad.
RETRY_S = 1.0


class KeyFileError(ValueError):
    """A key file that cannot be read or written; the message names it and says why."""


def keys_dir(cfg: OvisConfig) -> Path:
    """The folder of this configuration's key files."""
    return Path(cfg.trust.keys_dir or Path(cfg.service.state_dir) / "keys")


def private_key_path(cfg: OvisConfig, role: str) -> Path:
    """Where ``role`` keeps its private key."""
    return keys_dir(cfg) / f"{role}.key"


def public_key_path(cfg: OvisConfig, role: str) -> Path:
    """The public key of ``role`` that this configuration trusts."""
    t = cfg.trust
    named = {
        "calibrator": t.calibrator_public,
        "pose": t.pose_public,
        "fusion": t.fusion_public,
        "planner": t.planner_public,
    }
    return Path(named[role]) if named[role] else keys_dir(cfg) / f"{role}.pub"


def key_id(public: Ed25519PublicKey) -> bytes:
    """A public key's short name: the first 8 bytes of the SHA-256 of its 32 raw bytes."""
    raw = public.public_bytes(serialization.Encoding.Raw, serialization.PublicFormat.Raw)
    return hashlib.sha256(raw).digest()[:8]


def public_pem(public: Ed25519PublicKey) -> bytes:
    return public.public_bytes(
        serialization.Encoding.PEM, serialization.PublicFormat.SubjectPublicKeyInfo
    )


def _read_private(path: Path) -> Ed25519PrivateKey:
    try:
        key = serialization.load_pem_private_key(path.read_bytes(), password=None)
    except (OSError, ValueError, TypeError, UnsupportedAlgorithm) as exc:
        raise KeyFileError(f"cannot read the private key {path}: {exc}") from None
    if not isinstance(key, Ed25519PrivateKey):
        raise KeyFileError(f"{path} is not an Ed25519 private key")
    return key


def load_or_create_private(path: Path) -> Ed25519PrivateKey:
    """The private key in ``path``, made there first if there is none (mode 0600; two
    processes making it at once end up with the same one), with its public key beside
    it (``<name>.pub``, rewritten when missing or different)."""
    if not path.exists():
        key = Ed25519PrivateKey.generate()
        pem = key.private_bytes(
            serialization.Encoding.PEM,
            serialization.PrivateFormat.PKCS8,
            serialization.NoEncryption(),
        )
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)  # mode 0600
            try:
                with os.fdopen(fd, "wb") as fh:
                    fh.write(pem)
                    fh.flush()
                    os.fsync(fh.fileno())
                with contextlib.suppress(FileExistsError):  # another process made it first
                    os.link(tmp, path)
            finally:
                Path(tmp).unlink(missing_ok=True)
        except OSError as exc:
            raise KeyFileError(f"cannot write the private key {path}: {exc}") from None
    key = _read_private(path)
    pub, pem = path.with_suffix(".pub"), public_pem(key.public_key())
    try:
        if not pub.exists() or pub.read_bytes() != pem:
            write_atomic(pub, pem)
            pub.chmod(0o644)
    except OSError as exc:
        raise KeyFileError(f"cannot write the public key {pub}: {exc}") from None
    return key


def load_public(path: Path) -> Ed25519PublicKey:
    """The Ed25519 public key of a PEM file (KeyFileError saying why not)."""
    try:
        key = serialization.load_pem_public_key(path.read_bytes())
    except FileNotFoundError:
        raise KeyFileError(f"no public key at {path}") from None
    except (OSError, ValueError, UnsupportedAlgorithm) as exc:
        raise KeyFileError(f"cannot read the public key {path}: {exc}") from None
    if not isinstance(key, Ed25519PublicKey):
        raise KeyFileError(f"{path} is not an Ed25519 public key")
    return key


class PublicKeyFile:
    """A trusted public key read from its file when first needed, and read again (at
    most every ``RETRY_S``) while it is missing or bad: a stage may start before the
    stage that makes the key. Thread-safe."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.problem = f"no public key at {path} yet"
        self._key: Ed25519PublicKey | None = None
        self._tried = -RETRY_S
        self._lock = threading.Lock()

    def key(self, now: float | None = None) -> Ed25519PublicKey | None:
        """The key, or None (``problem`` says why)."""
        now = time.monotonic() if now is None else now
        with self._lock:
            if self._key is None and now - self._tried >= RETRY_S:
                self._tried = now
                try:
                    self._key = load_public(self.path)
                except KeyFileError as exc:
                    self.problem = str(exc)
            return self._key
