"""What the physical-world tests share: skip with the reason where MuJoCo cannot render
(never in CI: ``.ci/run`` installs EGL and Mesa, and sets ``OVIS_REQUIRE_PHYSICAL``, which
turns the skip into a failure).

Without an OpenGL back-end, importing MuJoCo itself fails: a module that imports it (or
``ovis.common.physical``'s world, model, camera, grid, marks or dataset) at its top calls
:func:`skip_module_without_physical` first; a test that only runs commands is marked
:data:`needs_physical`."""

from __future__ import annotations

import os
import threading
from typing import Any

import pytest

from ovis.common.messages import RobotDrive, Topics, decode
from ovis.common.physical.availability import why_unavailable

REASON = why_unavailable()
#: CI: the physical world must run, a machine without it fails instead of skipping
REQUIRED = bool(os.environ.get("OVIS_REQUIRE_PHYSICAL"))

#: Mark a test (or a module, as ``pytestmark``) that needs the physical world.
needs_physical = pytest.mark.skipif(
    REASON is not None and not REQUIRED,
    reason=f"physical world unavailable: {REASON}",
)


def skip_module_without_physical() -> None:
    """Skip the calling test module, with the reason, where the physical world cannot
    render (unless ``OVIS_REQUIRE_PHYSICAL`` is set: then its imports fail, and so does
    the run). Call it before importing MuJoCo or the modules that do."""
    if REASON is not None and not REQUIRED:
        pytest.skip(f"physical world unavailable: {REASON}", allow_module_level=True)


class DriveReports:
    """Every :class:`~ovis.common.messages.RobotDrive` a driven physical world publishes
    (``ovis/<arena>/robots/*/drive``), kept as it comes, for tests of ``ovis up --drive``."""

    def __init__(self, session: Any, topics: Topics) -> None:
        self._lock = threading.Lock()
        self._all: list[RobotDrive] = []
        session.declare_subscriber(topics.drives_all, self._on_sample)

    def _on_sample(self, sample: Any) -> None:
        report = decode(sample.payload.to_bytes(), RobotDrive)
        with self._lock:
            self._all.append(report)

    def all(self) -> list[RobotDrive]:
        with self._lock:
            return list(self._all)

    @property
    def last(self) -> RobotDrive:
        with self._lock:
            return self._all[-1]

    def followed(self) -> int:
        """The commands the robot (the last reported) followed so far (0: no report)."""
        with self._lock:
            return self._all[-1].commands if self._all else 0
