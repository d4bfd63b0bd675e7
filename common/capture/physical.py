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

**Driven** (``[navigation] drive``, ``ovis up --drive``): the scene is the seed's
scenario of ``[navigation] case`` (:func:`~ovis.common.navigation.scenarios.make_scenario`),
its robots differential-drive bodies following the commands :meth:`PhysicalSource.command`
hands them (each robot's firmware, :class:`~ovis.common.navigation.base.RobotBase`,
with its watchdog); between two frames the physics runs forward
(:class:`~ovis.common.navigation.driving.Driving`) instead of being set to the
instant, and :meth:`PhysicalSource.drives` says what each robot did.

**Unplugged** (:attr:`PhysicalSource.unplugged`, ``SIGUSR1`` to the capture toggles
it): the camera gives no frame (:class:`~ovis.common.capture.sources.NoFrameError` at
each instant a frame was due) while the world and its robots run on, so that what the
robots do when the camera's source is lost can be tried mid-drive.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from ovis.common.capture.frame_source import NoFrameError
from ovis.common.config import OvisConfig
from ovis.common.navigation.base import DriveCommand
from ovis.common.navigation.driving import Driving
from ovis.common.navigation.scenarios import RobotTask, make_scenario
from ovis.common.physical.scene import random_scene
from ovis.common.physical.world import PhysicalWorld
from ovis.common.sim.arena import FrameTruth

__all__ = ["UNPLUGGED_WAIT_S", "PhysicalSource"]

#: Seconds an unplugged camera running free (``fps`` 0) waits before it says it gave no
#: frame (on a clock it waits for the instant the frame was due).
UNPLUGGED_WAIT_S = 0.1


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
        nav = config.navigation
        self.tasks: list[RobotTask] = []
        self.driving: Driving | None = None
        self._lock = threading.Lock()  # commands come from the network's thread
        #: each robot's newest command received: (v cm/s, ω °/s, its frame's stamp ns)
        self.received: dict[int, tuple[float, float, int]] = {}
        if nav.drive:
            scenario = make_scenario(config, seed, [config.camera])
            self.scene, self.tasks = scenario.scene, scenario.tasks
            self.world = PhysicalWorld(self.scene, config, [config.camera], driven=True)
            self.world.set_time(0.0)
            self.driving = Driving(self.world, self.tasks, nav)
        else:
            self.scene = random_scene(config, seed, [config.camera])
            self.world = PhysicalWorld(self.scene, config, [config.camera])
        self.fps = float(config.service.fps)
        self._clock, self._sleep = clock, sleep
        self._t0: int | None = None
        self._next = 0
        #: frames whose instant passed while an earlier one was rendering (not rendered)
        self.missed = 0
        #: the camera gives no frame, the world runs on (module docstring)
        self.unplugged = False
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
        if self.driving is None:
            self.world.set_time(t_s)
        else:
            with self._lock:
                self.driving.advance_to(t_s)
        if self.unplugged:
            if self.fps <= 0:  # no frame was due: do not ask again at once
                self._sleep(UNPLUGGED_WAIT_S)
            raise NoFrameError(f"the physical world's camera is unplugged (t = {t_s:.2f} s)")
        image = self.world.render(k)
        return image, self.world.truth(k, stamp_ns=stamp)

    def world_s(self, stamp_ns: int) -> float:
        """The world's time (s) of a capture-clock instant (ns)."""
        return 0.0 if self._t0 is None else (stamp_ns - self._t0) / 1e9

    def command(
        self, robot_id: int, v_cm_s: float, omega_deg_s: float, frame_ns: int, stop: str = ""
    ) -> None:
        """A command for a driven robot, made from the frame stamped ``frame_ns``,
        received now (nothing when the robots are not driven)."""
        if self.driving is None:
            return
        now = self.world_s(self._clock())
        with self._lock:
            received = max(now, self.world.t_s)
            command = DriveCommand(v_cm_s, omega_deg_s, self.world_s(frame_ns), received, stop)
            self.driving.receive(robot_id, command)
            self.received[robot_id] = (v_cm_s, omega_deg_s, frame_ns)

    def drives(self) -> list[dict[str, object]]:
        """What each driven robot did so far (the fields of a ``RobotDrive`` message)."""
        d = self.driving
        if d is None:
            return []
        with self._lock:
            truth = {o.id: o for o in self.world.truth(0).objects}
            out = []
            for task in self.tasks:
                me, base = truth[task.id], d.bases[task.id]
                reached = d.reached_s[task.id]
                v, omega, frame_ns = self.received.get(task.id, (None, None, None))
                out.append(
                    {
                        "robot_id": task.id,
                        "t_s": self.world.t_s,
                        "x_cm": me.x_cm,
                        "y_cm": me.y_cm,
                        "heading_deg": me.heading_deg,
                        "v_cm_s": base.speed_cm_s,
                        "omega_deg_s": self.world.yaw_rate_deg_s(task.id),
                        "goal_cm": task.goal_cm,
                        "goal_reached": reached is not None,
                        "time_s": reached,
                        "collisions": d.contacts[task.id],
                        "min_clearance_cm": (
                            d.clearance[task.id] if math.isfinite(d.clearance[task.id]) else None
                        ),
                        "commands": base.followed,
                        "stopped": base.stopped,
                        "command_v_cm_s": v,
                        "command_omega_deg_s": omega,
                        "command_stamp_ns": frame_ns,
                    }
                )
            return out

    def close(self) -> None:
        self.world.close()
