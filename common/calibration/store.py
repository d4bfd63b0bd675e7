"""Versioned calibrations on disk: the newest versions kept, the newest good one in use.

Layout of the store folder::

    calibration-v0001.json   one file per version, never rewritten
    calibration-v0002.json
    current.json             a copy of the newest version
    epoch                    the store's random id, made once (see ``epoch()``)

Every file is written atomically, so a crash at any moment leaves the last good
calibration loadable. Loading takes the highest version that loads and passes the
caller's check; a corrupt, hand-edited or invalid file is skipped with a message naming
the problem. Saving keeps the newest ``keep`` versions (older files are deleted), so a
client that asks for calibration after calibration cannot fill the disk. A folder that
cannot be written (full, read-only) is a :class:`StoreWriteError` naming why, and the
store remembers it (``problem``) until a write works again.
"""

from __future__ import annotations

import contextlib
import os
import re
import secrets
from collections.abc import Callable
from pathlib import Path

import msgspec

from ovis.common.atomic import write_atomic
from ovis.common.calibration.file import (
    Calibration,
    CalibrationFileError,
    load_calibration,
    save_calibration,
)
from ovis.common.config import KEEP_CALIBRATIONS

__all__ = ["PROBE_BYTES", "CalibrationStore", "StoreWriteError"]

_VERSION_RE = re.compile(r"^calibration-v(\d{4,})\.json$")
_EPOCH_RE = re.compile(r"^[0-9a-f]{16}$")
#: What :meth:`CalibrationStore.writable` writes to find out: room for a calibration
#: file and its copy in ``current.json``.
PROBE_BYTES = 64 << 10


class StoreWriteError(OSError):
    """The store's folder cannot be written; the message says why and where."""


def _why(exc: OSError, folder: Path) -> str:
    """An OS error as a short reason: "No space left on device in /x/ovis-state"."""
    return f"{exc.strerror or exc} in {folder}"


class CalibrationStore:
    """A folder of versioned calibration files, keeping the newest ``keep``."""

    def __init__(self, folder: Path | str, keep: int = KEEP_CALIBRATIONS) -> None:
        if keep < 1:
            raise ValueError(f"a calibration store keeps at least 1 version, not {keep}")
        self.folder = Path(folder)
        self.keep = keep
        #: why the last write failed (None: it worked, or none was tried)
        self.problem: str | None = None
        #: the old versions the last :meth:`prune` could not delete, each with why
        self.not_deleted: list[str] = []

    def _write(self, write: Callable[[], None]) -> None:
        """Run ``write``; an OSError becomes a StoreWriteError and the store's problem."""
        try:
            write()
        except OSError as exc:
            self.problem = _why(exc, self.folder)
            raise StoreWriteError(self.problem) from exc
        self.problem = None

    def versions(self) -> list[int]:
        """Versions present on disk (whatever their content), ascending."""
        if not self.folder.is_dir():
            return []
        found = (_VERSION_RE.match(p.name) for p in self.folder.iterdir())
        return sorted(int(m.group(1)) for m in found if m)

    def epoch(self) -> str:
        """The store's identity: 16 random hex digits, made the first time and kept in
        the file ``epoch``. Every calibration saved here carries it, so that stages
        compare versions only within one store (a calibrator that lost its folder, or a
        forger, starts another series instead of shadowing this one)."""
        path = self.folder / "epoch"
        try:
            text = path.read_text(encoding="ascii").strip()
        except (OSError, UnicodeDecodeError):
            text = ""
        if _EPOCH_RE.fullmatch(text):
            return text
        text = secrets.token_hex(8)
        self._write(lambda: write_atomic(path, text.encode("ascii") + b"\n"))
        return text

    def writable(self) -> str | None:
        """Why a calibration could not be saved now (the folder cannot be made, or
        :data:`PROBE_BYTES` cannot be written in it), or None; kept as ``problem``."""
        probe = self.folder / ".write-probe"

        def write() -> None:
            self.folder.mkdir(parents=True, exist_ok=True)
            try:
                write_atomic(probe, bytes(PROBE_BYTES))
            finally:
                probe.unlink(missing_ok=True)

        try:
            self._write(write)
        except StoreWriteError:
            return self.problem
        return None

    def path(self, version: int) -> Path:
        return self.folder / f"calibration-v{version:04d}.json"

    def latest(
        self, check: Callable[[Calibration], str | None] | None = None
    ) -> tuple[Calibration | None, list[str]]:
        """The newest calibration that loads and that ``check`` finds no problem with,
        and the problems of the newer ones skipped."""
        problems: list[str] = []
        for version in reversed(self.versions()):
            path = self.path(version)
            try:
                calib = load_calibration(path)
            except CalibrationFileError as exc:
                problems.append(str(exc))
                continue
            problem = f"says version {calib.version}, its name {version}"
            if calib.version == version:
                problem = check(calib) if check is not None else None
            if problem is not None:
                problems.append(f"{path}: {problem}")
                continue
            return calib, problems
        return None, problems

    def save(self, calibration: Calibration) -> Calibration:
        """Store ``calibration`` as the next version and delete the versions beyond the
        newest ``keep``; return it with its version and epoch set. StoreWriteError
        (nothing saved) when the folder cannot be written."""
        versions = self.versions()
        version = (versions[-1] if versions else 0) + 1
        calibration = msgspec.structs.replace(calibration, version=version, epoch=self.epoch())

        def write() -> None:
            self.folder.mkdir(parents=True, exist_ok=True)
            try:
                save_calibration(self.path(version), calibration)
                save_calibration(self.folder / "current.json", calibration)
            except OSError:
                with contextlib.suppress(OSError):  # all or nothing
                    self.path(version).unlink(missing_ok=True)
                raise

        self._write(write)
        self.prune()
        return calibration

    def prune(self) -> list[int]:
        """Delete the versions older than the newest ``keep``; the versions deleted. A
        file that cannot be deleted stays, to be tried again next time, and is named
        with why in :attr:`not_deleted` (for the calibrator to count and say)."""
        deleted, self.not_deleted = [], []
        for version in self.versions()[: -self.keep]:
            path = self.path(version)
            try:
                os.unlink(path)
            except FileNotFoundError:
                pass
            except OSError as exc:
                self.not_deleted.append(f"{path}: {exc.strerror or exc}")
                continue
            deleted.append(version)
        return deleted
