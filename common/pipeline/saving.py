"""What the calibrator says while its store cannot be written (a full or read-only
state folder): its status, and the reply to a calibration that could not be saved.
A calibration that is not saved is not used: a restart would lose it."""

from __future__ import annotations

import msgspec

from ovis.common.messages import ServiceStatus

__all__ = ["CANNOT_SAVE", "cannot_save_status", "cannot_save_text"]

#: How the calibrator's state begins while it cannot save (then ": <reason>").
CANNOT_SAVE = "cannot save"


def cannot_save_text(problem: str, current: str) -> str:
    """The reply's error: why, what to do, and which calibration stays in use."""
    return (
        f"{CANNOT_SAVE}: {problem}: free space there or make it writable (or set [service] "
        f"state_dir to a folder that is), then ask again; the calibration in use stays "
        f"{current}"
    )


def cannot_save_status(status: ServiceStatus, problem: str | None) -> ServiceStatus:
    """``status`` with state ``cannot save: <problem>`` (and the problem as its reason)
    while there is one, whatever else it says."""
    if problem is None:
        return status
    return msgspec.structs.replace(status, state=f"{CANNOT_SAVE}: {problem}", reason=problem)
