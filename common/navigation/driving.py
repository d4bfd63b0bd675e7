"""Robots of the physical world following their commands: each robot's firmware
(:class:`~ovis.common.navigation.base.RobotBase`) sets its wheels from the commands it
has received, the physics runs, and what happened is counted — for ``ovis navigate``'s
lock-step runs and for the live world (``ovis up --drive``) alike.

:meth:`Driving.advance_to` runs the world in steps of :data:`CHUNK_S`; after each, per
robot: a **contact** is each new touch of another solid (MuJoCo's contacts), the
**clearance** the least distance to any other solid so far (MuJoCo's geometry), and the
robot **reached** its goal the first time its true centre is within
``goal_tolerance_cm`` of it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from ovis.common.config import NavigationConfig
from ovis.common.navigation.base import DriveCommand, RobotBase
from ovis.common.navigation.scenarios import RobotTask
from ovis.common.physical.world import PhysicalWorld

__all__ = ["CHUNK_S", "Driving"]

#: Physics between two looks at the firmware, contacts and clearance (s).
CHUNK_S = 0.01


class Driving:
    """The driven robots of ``world`` (one task each) under ``nav``'s rules."""

    def __init__(
        self, world: PhysicalWorld, tasks: Sequence[RobotTask], nav: NavigationConfig
    ) -> None:
        self.world = world
        self.nav = nav
        self.tasks = {t.id: t for t in tasks}
        self.bases = {i: RobotBase.of(nav) for i in self.tasks}
        self.reached_s: dict[int, float | None] = dict.fromkeys(self.tasks)
        self.contacts = dict.fromkeys(self.tasks, 0)
        self.clearance = dict.fromkeys(self.tasks, math.inf)
        self._touching: set[tuple[int, int]] = set()

    def receive(self, robot_id: int, command: DriveCommand) -> None:
        """A command for robot ``robot_id`` (ignored for a robot not driven here)."""
        base = self.bases.get(robot_id)
        if base is not None:
            base.receive(command)

    def advance_to(self, t_s: float) -> None:
        """Run the world to ``t_s`` (module docstring); nothing when it is there."""
        while self.world.t_s < t_s - 1e-9:
            now = self.world.t_s
            step = min(CHUNK_S, t_s - now)
            for ident, base in self.bases.items():
                self.world.set_wheels(ident, *base.update(now, step))
            self.world.advance(step, settle=False)
            self._count()
        self.world.settle()

    def _count(self) -> None:
        pairs = set(self.world.touching())
        for ident, _other in pairs - self._touching:
            self.contacts[ident] += 1
        self._touching = pairs
        tolerance = self.nav.goal_tolerance_cm
        for ident, task in self.tasks.items():
            self.clearance[ident] = min(self.clearance[ident], self.world.clearance_cm(ident))
            x, y = self.world.position_cm(ident)
            gx, gy = task.goal_cm
            if self.reached_s[ident] is None and math.hypot(x - gx, y - gy) <= tolerance:
                self.reached_s[ident] = self.world.t_s
