"""Which calibration a stage uses: the calibrator's, when it is physically valid and
works here.

The calibrator is the one source of truth. A stage does not take a calibration pushed on
the calibration topic (anyone on the bus can publish there): a push only makes it ask
the calibrator's queryable at once, and it asks anyway every :data:`RECONCILE_S`. It
adopts the calibrator's answer whenever its identity (epoch, version) differs from the
one in use — even a lower version — provided :func:`calibration_problem` finds nothing
wrong. A calibration that makes the stage fail on a frame before it has worked once is
rolled back to the last one that worked, and not taken again (until the calibrator
answers with another one).
"""

from __future__ import annotations

import threading

from ovis.common.calibration.file import Calibration
from ovis.common.calibration.validity import calibration_problem
from ovis.common.config import OvisConfig

__all__ = ["RECONCILE_S", "CalibrationFollower", "Identity", "identity", "label"]

#: A stage asks the calibrator for its current calibration this often (seconds), so a
#: calibration it should not have is undone within this time plus a query's round trip.
RECONCILE_S = 2.0

Identity = tuple[str, int]


def identity(calib: Calibration) -> Identity:
    """What names a calibration: the calibrator's epoch (its store's random id) and the
    version in that store."""
    return calib.epoch, calib.version


def label(calib: Calibration) -> str:
    """``v3`` or ``v3@1a2b3c4d`` (with the first 8 characters of the epoch)."""
    return f"v{calib.version}" + (f"@{calib.epoch[:8]}" if calib.epoch else "")


class CalibrationFollower:
    """The calibration in use, the last one that worked on a frame, and the ones refused
    (thread-safe: the calibrator's answers come on another thread than the frames)."""

    def __init__(self, config: OvisConfig, initial: Calibration) -> None:
        self.config = config
        self.current = initial
        self.last_good = initial
        self.refused: dict[Identity, str] = {}  # why each was refused
        self.authority: Identity | None = None  # the calibrator's last answer
        self._lock = threading.Lock()

    def offer(self, calib: Calibration) -> tuple[bool, str | None]:
        """The calibrator answered ``calib``: (adopted?, why it was refused — said once
        per calibration, None otherwise)."""
        key = identity(calib)
        with self._lock:
            self.authority = key
            if key == identity(self.current):
                return False, None
            if key in self.refused:
                return False, None
            problem = calibration_problem(calib, self.config)
            if problem is not None:
                self.refused[key] = problem
                return False, problem
            self.current = calib
            return True, None

    def worked(self, calib: Calibration) -> None:
        """``calib`` produced an output: it is the one to roll back to."""
        with self._lock:
            if identity(calib) == identity(self.current):
                self.last_good = calib

    def failed(self, calib: Calibration, error: str) -> Calibration | None:
        """Processing a frame with ``calib`` raised ``error``: the calibration to roll back
        to when ``calib`` is in use and has never worked here, else None."""
        with self._lock:
            key = identity(calib)
            if key != identity(self.current) or key == identity(self.last_good):
                return None
            self.refused[key] = f"calibration {label(calib)} failed on a frame here: {error}"
            self.current = self.last_good
            return self.last_good

    def problem(self) -> str | None:
        """Why the stage does not use the calibrator's calibration (its status says it is
        degraded), or None."""
        with self._lock:
            if self.authority is None or self.authority == identity(self.current):
                return None
            return self.refused.get(self.authority)
