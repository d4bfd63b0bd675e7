"""Which calibration a stage uses: the calibrator's, when it is physically valid and
works here.

The calibrator is the one source of truth. A stage does not take a calibration pushed on
the calibration topic (anyone on the bus can publish there): a push with the
calibrator's proof only makes it ask the calibrator's queryable at once, and it asks
anyway every :data:`RECONCILE_S`, for every answer (:func:`pick`). Only answers that
carry the calibrator's proof of origin (:mod:`ovis.common.trust`) count, and of them
only one :func:`newer` than the calibration in use (a replayed old one is refused); it
is adopted provided :func:`calibration_problem` finds nothing wrong. An unproven or
replayed answer is a conflict: the stage says ``calibration_conflict`` with its source
for :data:`CONFLICT_HOLD_S` after the last one. A calibration that makes the stage fail
on a frame before it has worked once is rolled back to the last one that worked, and
not taken again (until the calibrator answers with another one).
"""

from __future__ import annotations

import threading
import time

import msgspec

from ovis.common.calibration.file import Calibration
from ovis.common.calibration.validity import calibration_problem
from ovis.common.config import OvisConfig

__all__ = [
    "CONFLICT_HOLD_S",
    "RECONCILE_S",
    "Answer",
    "CalibrationFollower",
    "Identity",
    "identity",
    "label",
    "newer",
    "pick",
]

#: A stage asks the calibrator for its current calibration this often (seconds), so a
#: calibration it should not have is undone within this time plus a query's round trip.
RECONCILE_S = 2.0

#: A stage says ``calibration_conflict`` this long after the last unproven or replayed
#: calibration it saw (two rounds of asking: it clears once the forger is gone).
CONFLICT_HOLD_S = 2 * RECONCILE_S

Identity = tuple[str, int]


def identity(calib: Calibration) -> Identity:
    """What names a calibration: the calibrator's epoch (its store's random id) and the
    version in that store."""
    return calib.epoch, calib.version


def label(calib: Calibration) -> str:
    """``v3`` or ``v3@1a2b3c4d`` (with the first 8 characters of the epoch)."""
    return f"v{calib.version}" + (f"@{calib.epoch[:8]}" if calib.epoch else "")


def newer(calib: Calibration, than: Calibration) -> bool:
    """Whether ``calib`` may replace ``than``: anything replaces the configured camera
    (version 0); within one store (epoch) a higher version; from another store (the
    calibrator's folder was replaced) one made later."""
    if than.version == 0:
        return True
    if calib.epoch == than.epoch:
        return calib.version > than.version
    return bool(calib.created) and calib.created > than.created


class Answer(msgspec.Struct, frozen=True):
    """One reply to the calibration query: who sent it, the calibration (None when it
    could not be decoded) and why its proof of origin fails (None: proven)."""

    source: str
    calibration: Calibration | None
    unproven: str | None = None


def pick(held: Calibration, answers: list[Answer]) -> tuple[Calibration | None, list[str]]:
    """The proven answer to adopt (None: keep ``held``) and the conflicts found: each
    unproven answer, each proven one older than ``held`` (a replay) and, when several
    proven answers are newer, all but the newest."""
    conflicts = [f"{a.source}: refused, {a.unproven}" for a in answers if a.unproven]
    proven = {identity(a.calibration): a for a in answers if a.calibration and not a.unproven}
    fresh = []
    for a in proven.values():
        calib = a.calibration
        assert calib is not None
        if newer(calib, held):
            fresh.append(a)
        elif identity(calib) != identity(held):
            conflicts.append(
                f"{a.source}: refused {label(calib)}, a replay (not newer than {label(held)})"
            )
    if not fresh:
        return None, conflicts
    best = fresh[0]
    for a in fresh[1:]:
        if newer(a.calibration, best.calibration):  # type: ignore[arg-type]
            best = a
    conflicts += [
        f"{a.source}: refused {label(a.calibration)}, older than {label(best.calibration)}"  # type: ignore[arg-type]
        for a in fresh
        if a is not best
    ]
    return best.calibration, conflicts


class CalibrationFollower:
    """The calibration in use, the last one that worked on a frame, and the ones refused
    (thread-safe: the calibrator's answers come on another thread than the frames)."""

    def __init__(self, config: OvisConfig, initial: Calibration) -> None:
        self.config = config
        self.current = initial
        self.last_good = initial
        self.refused: dict[Identity, str] = {}  # why each was refused
        self.authority: Identity | None = None  # the calibrator's last answer
        self._conflict: tuple[str, float] | None = None  # the last one, and when
        self._lock = threading.Lock()

    def conflict(self, text: str, now: float) -> None:
        """An unproven or replayed calibration was seen at ``now`` (monotonic s)."""
        with self._lock:
            self._conflict = (text, now)

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

    def problem(self, now: float | None = None) -> str | None:
        """Why the stage does not use the calibrator's calibration, or has seen a
        calibration conflict within ``CONFLICT_HOLD_S`` (its status says it is degraded),
        or None."""
        now = time.monotonic() if now is None else now
        with self._lock:
            if self._conflict is not None and now - self._conflict[1] < CONFLICT_HOLD_S:
                return f"calibration_conflict: {self._conflict[0]}"
            if self.authority is None or self.authority == identity(self.current):
                return None
            return self.refused.get(self.authority)
