"""What every frame source is (:class:`FrameSource`) and how it fails: it cannot deliver
(:class:`SourceError`), gave nothing this time (:class:`NoFrameError`), or ended for good
(:class:`SourceEndedError`). Apart from the sources themselves so that a source in its own
module (the physical world's, :mod:`ovis.common.capture.physical`) needs none of the others.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from ovis.common.sim.arena import FrameTruth

__all__ = ["FrameSource", "NoFrameError", "SourceEndedError", "SourceError"]


class SourceError(RuntimeError):
    """A source that cannot deliver frames (missing camera, unreadable file, ended)."""


class NoFrameError(SourceError):
    """A source still open that gave no frame this time (the physical world's camera
    unplugged, its world running on): the loss is said, the source kept and read again."""


class SourceEndedError(SourceError):
    """A folder or video that ended with looping off: it has nothing more to give. The
    text starts with "ended"."""


class FrameSource(Protocol):
    description: str

    def read(self) -> tuple[NDArray[np.uint8], FrameTruth | None]:
        """The next frame and, for simulated frames, its ground truth."""
        ...

    def close(self) -> None: ...
