"""Rejected candidates: calibrations the quality gate refused to publish, kept aside in
the store's ``rejected/`` folder (never as a version of the store) so that an operator
can look at what was refused and why.

Each candidate is two files, written atomically: ``candidate-<UTC time>.json`` (a
calibration file, usable with ``ovis detect --calibration``) and
``candidate-<UTC time>.reason`` (the one-line reason). Only the newest
:data:`KEEP_REJECTED` are kept: a client asking for poisoned calibrations cannot fill the
disk through this folder.
"""

from __future__ import annotations

import time
from pathlib import Path

from ovis.common.atomic import write_atomic
from ovis.common.calibration.file import Calibration, save_calibration

__all__ = ["KEEP_REJECTED", "REJECTED_FOLDER", "save_rejected"]

REJECTED_FOLDER = "rejected"
KEEP_REJECTED = 10


def save_rejected(store_folder: Path | str, candidate: Calibration, reason: str) -> Path:
    """Keep ``candidate`` and why it was refused in ``<store_folder>/rejected/``; return
    the calibration file's path. The oldest candidates beyond :data:`KEEP_REJECTED` go."""
    folder = Path(store_folder) / REJECTED_FOLDER
    stamp = time.strftime("%Y%m%dT%H%M%S", time.gmtime()) + f"{time.time_ns() % 10**9:09d}"
    path = folder / f"candidate-{stamp}.json"
    save_calibration(path, candidate)
    write_atomic(path.with_suffix(".reason"), reason.encode() + b"\n")
    for old in sorted(folder.glob("candidate-*.json"))[:-KEEP_REJECTED]:
        old.unlink(missing_ok=True)
        old.with_suffix(".reason").unlink(missing_ok=True)
    return path
