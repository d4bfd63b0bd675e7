"""Versioned calibrations on disk: every calibration kept, the newest good one in use.

Layout of the store folder::

    calibration-v0001.json   one file per version, never rewritten
    calibration-v0002.json
    current.json             a copy of the newest version
    epoch                    the store's random id, made once (see ``epoch()``)

Every file is written atomically, so a crash at any moment leaves the last good
calibration loadable. Loading takes the highest version that validates; a corrupt or
hand-edited file is skipped with a message naming the problem.
"""

from __future__ import annotations

import re
import secrets
from pathlib import Path

import msgspec

from ovis.common.atomic import write_atomic
from ovis.common.calibration.file import (
    Calibration,
    CalibrationFileError,
    load_calibration,
    save_calibration,
)

__all__ = ["CalibrationStore"]

_VERSION_RE = re.compile(r"^calibration-v(\d{4,})\.json$")
_EPOCH_RE = re.compile(r"^[0-9a-f]{16}$")


class CalibrationStore:
    """A folder of versioned calibration files."""

    def __init__(self, folder: Path | str) -> None:
        self.folder = Path(folder)

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
        write_atomic(path, text.encode("ascii") + b"\n")
        return text

    def path(self, version: int) -> Path:
        return self.folder / f"calibration-v{version:04d}.json"

    def latest(self) -> tuple[Calibration | None, list[str]]:
        """The newest calibration that loads, and the problems of newer ones skipped."""
        problems: list[str] = []
        for version in reversed(self.versions()):
            try:
                calib = load_calibration(self.path(version))
            except CalibrationFileError as exc:
                problems.append(str(exc))
                continue
            if calib.version != version:
                problems.append(
                    f"{self.path(version)} says version {calib.version}, its name {version}"
                )
                continue
            return calib, problems
        return None, problems

    def save(self, calibration: Calibration) -> Calibration:
        """Store ``calibration`` as the next version; return it with that version set."""
        versions = self.versions()
        version = (versions[-1] if versions else 0) + 1
        calibration = msgspec.structs.replace(calibration, version=version, epoch=self.epoch())
        self.folder.mkdir(parents=True, exist_ok=True)
        save_calibration(self.path(version), calibration)
        save_calibration(self.folder / "current.json", calibration)
        return calibration
