"""Which side a robot passes its critical body on, chosen by the room the arena leaves.

A fuzzy controller's rules say "an obstacle on the left: deviate so much to the right";
which side they send the robot to is fixed by the rules, whatever the arena leaves
there, and a robot sent towards a near edge runs along it into obstacles crossing
towards that edge (the failures of docs/navigation.md). A controller with
``side_by_room`` sees its inputs in a frame turned to the arena: where the arena leaves
more room on the robot's right of its goal direction than on its left, the angle in
and the deviation out are mirrored (left ↔ right), so that the rules' "left" is always
the roomier side. The room on a side is the distance from the robot along the normal
of its goal direction to the arena's edge (beyond the robot's radius).

The side is chosen when a body becomes the robot's critical one and kept while it
stays critical (:class:`Sides`): a robot passing an obstacle does not change sides
half-way because it crossed the arena's middle.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from ovis.common.navigation.observe import Situation
from ovis.common.navigation.steering import Arena, goal_direction

__all__ = ["Sides", "room_cm", "roomier_right"]

FloatArray = NDArray[np.float64]


def _reach(x: FloatArray, y: FloatArray, dx: FloatArray, dy: FloatArray, arena: Arena):
    """Distance (cm) from (x, y) along the unit direction (dx, dy) to the arena's edge."""
    with np.errstate(divide="ignore", invalid="ignore"):
        tx = np.where(dx > 0, (arena.x1 - x) / dx, np.where(dx < 0, (arena.x0 - x) / dx, np.inf))
        ty = np.where(dy > 0, (arena.y1 - y) / dy, np.where(dy < 0, (arena.y0 - y) / dy, np.inf))
    return np.maximum(np.minimum(tx, ty), 0.0)


def room_cm(s: Situation, arena: Arena) -> tuple[FloatArray, FloatArray]:
    """Room (cm, beyond each robot's radius) on the left and on the right of each
    robot's goal direction (counter-clockwise is left)."""
    to_goal, _ = goal_direction(s)
    nx, ny = -np.sin(to_goal), np.cos(to_goal)
    left = _reach(s.x, s.y, nx, ny, arena) - s.radius
    right = _reach(s.x, s.y, -nx, -ny, arena) - s.radius
    return left, right


def roomier_right(s: Situation, arena: Arena) -> NDArray[np.bool_]:
    """Whether the arena leaves each robot more room on its right than on its left."""
    left, right = room_cm(s, arena)
    return right > left


class Sides:
    """Each robot's chosen side (module docstring): the key of the body it was chosen
    for (−1: none) and whether its frame is mirrored. One per set of robots, kept
    between frames."""

    def __init__(self) -> None:
        self.key: NDArray[np.int64] | None = None
        self.mirror: NDArray[np.bool_] | None = None

    def choose(self, key: NDArray[np.int64], roomier: NDArray[np.bool_]) -> NDArray[np.bool_]:
        """Per robot, whether to mirror: as chosen before while ``key`` (its critical
        body's, −1: none) is the one it was chosen for, else ``roomier`` (right)."""
        key = np.asarray(key, dtype=np.int64)
        if self.key is None or self.mirror is None or self.key.shape != key.shape:
            self.key = np.full(key.shape, -1, dtype=np.int64)
            self.mirror = np.zeros(key.shape, dtype=bool)
        same = (key == self.key) & (key >= 0)
        mirror = np.where(same, self.mirror, np.asarray(roomier, bool))
        self.key, self.mirror = key.copy(), mirror
        return mirror
