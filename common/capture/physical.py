"""The physical world as a live source (``sim`` with ``[simulator] world = "physical"``):
each frame rendered by MuJoCo from the physics state at the instant it shows.

The source keeps a capture clock: frame k is due at ``t0 + k / fps`` (``t0``: the first
read; ``[service] fps``), shows the world at ``t = k / fps`` and is stamped with that
instant, the truth (:meth:`PhysicalWorld.truth`) with it. A read waits for the next
frame that is not yet due and renders it then; a frame whose instant passed while the
previous one was rendering is never rendered (a camera that cannot keep up misses
triggers): no frame shows an instant older than its stamp, and none is stamped later
than the instant it shows. Rendering costs far more than the light simulator's painting
(``benchmarks/``: the physical world's rows), so the frame rate a machine sustains is
bounded by it; at ``fps`` 0 each read renders the instant it starts.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from ovis.common.config import OvisConfig
from ovis.common.physical.scene import random_scene
from ovis.common.physical.world import PhysicalWorld
from ovis.common.sim.arena import FrameTruth

__all__ = ["PhysicalSource"]


class PhysicalSource:
    """The physical world of ``seed`` seen by ``config.camera``, live (module docstring).
    ``clock``: the capture clock (ns), ``sleep``: how to wait (s)."""

    #: paces itself: the capture must not wait between reads as well
    self_paced = True

    def __init__(
        self,
        config: OvisConfig,
        seed: int,
        *,
        clock: Callable[[], int] = time.time_ns,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        self.scene = random_scene(config, seed, [config.camera])
        self.world = PhysicalWorld(self.scene, config, [config.camera])
        self.fps = float(config.service.fps)
        self._clock, self._sleep = clock, sleep
        self._t0: int | None = None
        self._next = 0
        #: frames whose instant passed while an earlier one was rendering (not rendered)
        self.missed = 0
        phys = config.physical
        light = f"{phys.lights} lamp(s), shadows {'on' if phys.shadows else 'off'}"
        rate = f"{self.fps:g} frames/s" if self.fps > 0 else "as fast as it renders"
        self.description = (
            f"physical world (seed {seed}, MuJoCo, {light}), rendered when each frame is "
            f"due at {rate}"
        )

    def _due(self, k: int) -> int:
        assert self._t0 is not None
        return self._t0 + round(k * 1e9 / self.fps)

    def read(self) -> tuple[NDArray[np.uint8], FrameTruth | None]:
        now = self._clock()
        if self._t0 is None:
            self._t0 = now
        if self.fps > 0:
            k = self._next
            while self._due(k) < now:  # passed while the last one rendered: missed
                k += 1
            self.missed += k - self._next
            stamp = self._due(k)
            self._sleep(max(0.0, (stamp - self._clock()) / 1e9))
            t_s = k / self.fps
        else:
            k, stamp = self._next, now
            t_s = (now - self._t0) / 1e9
        self._next = k + 1
        self.world.set_time(t_s)
        image = self.world.render(k)
        return image, self.world.truth(k, stamp_ns=stamp)

    def close(self) -> None:
        self.world.close()
