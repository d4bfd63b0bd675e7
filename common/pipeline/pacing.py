"""The capture's pacing: frames at the configured rate, without catching up when late
(a burst of frames after a stall would only be dropped downstream)."""

from __future__ import annotations

import time
from collections.abc import Callable

__all__ = ["Pacer"]


class Pacer:
    """Says how long to wait before the next frame to keep ``fps`` (0: no wait)."""

    def __init__(self, fps: float, clock: Callable[[], float] = time.monotonic) -> None:
        self.period = 1.0 / fps if fps > 0 else 0.0
        self._clock = clock
        self._next = clock()

    def delay(self) -> float:
        """Seconds to wait after a frame before the next one; 0 when running late, and
        then the schedule restarts from now instead of trying to catch up."""
        if not self.period:
            return 0.0
        self._next += self.period
        delay = self._next - self._clock()
        if delay > 0:
            return delay
        self._next = self._clock()
        return 0.0
