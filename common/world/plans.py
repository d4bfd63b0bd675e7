"""Motion-planner inputs of every marked robot (paper §5.2 for each of them).

For robot R, every obstacle O and every *other* robot (a disk of its configured
``radius_cm``: an obstacle to R) gets the paper's distance ``|O − R| − r_O`` and two
signed angles, degrees in (−180, 180], counter-clockwise positive, of the direction
R → O (:func:`ovis.common.world.planner.planner_inputs`):

* ``angle_deg`` from R's goal direction (its own ``goal_cm``/``goal_angle_deg``, else
  ``[pose]``'s; None when it has no goal or stands on it);
* ``heading_angle_deg`` from R's heading.
"""

from __future__ import annotations

import math
from typing import Annotated, Literal

import msgspec
import numpy as np
from numpy.typing import NDArray

from ovis.common.config import PoseConfig
from ovis.common.world.planner import planner_inputs
from ovis.common.world.robots import RobotState

__all__ = ["RobotPlan", "TargetEntry", "robot_plans"]

Angle = Annotated[float, msgspec.Meta(gt=-180.0, le=180.0)]
Finite = Annotated[float, msgspec.Meta(ge=-1e12, le=1e12)]


class TargetEntry(msgspec.Struct, kw_only=True):
    """One obstacle or other robot, as robot ``RobotPlan.robot_id`` sees it."""

    target_id: Annotated[int, msgspec.Meta(ge=0)]
    target_kind: Literal["obstacle", "robot"]
    distance_cm: Finite
    angle_deg: Angle | None
    heading_angle_deg: Angle


class RobotPlan(msgspec.Struct, kw_only=True):
    """Planner inputs of one robot: its goal direction (deg from +X, None without a
    goal) and one entry per obstacle, then per other robot."""

    robot_id: Annotated[int, msgspec.Meta(ge=0)]
    goal_direction_deg: Finite | None
    entries: list[TargetEntry]


def _goal_direction(
    robot: RobotState, goal_xy: tuple[float, float] | None, goal_angle: float | None
) -> float | None:
    if goal_angle is not None:
        return float(goal_angle)
    if goal_xy is None:
        return None
    dx, dy = goal_xy[0] - robot.x_cm, goal_xy[1] - robot.y_cm
    if math.hypot(dx, dy) < 1e-9:
        return None
    return math.degrees(math.atan2(dy, dx))


def robot_plans(
    robots: list[RobotState],
    obstacle_ids: NDArray[np.int64],
    obstacles_xyr: NDArray[np.float64],
    pose: PoseConfig,
) -> list[RobotPlan]:
    """Planner inputs of each robot against the obstacles (ids, (n, 3) x, y, r in cm)
    and the other robots."""
    specs = {r.id: r for r in pose.robots}
    obstacles_xyr = np.asarray(obstacles_xyr, dtype=np.float64).reshape(-1, 3)
    robot_xyr = np.array([[r.x_cm, r.y_cm, r.radius_cm] for r in robots]).reshape(-1, 3)
    plans = []
    for k, robot in enumerate(robots):
        spec = specs.get(robot.id)
        own = spec is not None and (spec.goal_cm is not None or spec.goal_angle_deg is not None)
        goal_xy = spec.goal_cm if own else pose.goal_cm  # type: ignore[union-attr]
        goal_angle = spec.goal_angle_deg if own else pose.goal_angle_deg  # type: ignore[union-attr]
        others = np.arange(len(robots)) != k
        targets = np.concatenate([obstacles_xyr, robot_xyr[others]])
        ids = [*obstacle_ids.tolist(), *(r.id for r, o in zip(robots, others, strict=True) if o)]
        kinds = ["obstacle"] * len(obstacles_xyr) + ["robot"] * int(others.sum())
        xy = (robot.x_cm, robot.y_cm)
        relative = planner_inputs(xy, targets, goal_angle_deg=robot.heading_deg)
        direction = _goal_direction(robot, goal_xy, goal_angle)
        angles: list[float | None] = [None] * len(ids)
        if direction is not None:
            angles = planner_inputs(xy, targets, goal_angle_deg=direction).angle_deg.tolist()
        entries = [
            TargetEntry(
                target_id=int(i),
                target_kind=kind,  # type: ignore[arg-type]
                distance_cm=float(d),
                angle_deg=a,
                heading_angle_deg=float(h),
            )
            for i, kind, d, a, h in zip(
                ids, kinds, relative.distance_cm, angles, relative.angle_deg, strict=True
            )
        ]
        plans.append(RobotPlan(robot_id=robot.id, goal_direction_deg=direction, entries=entries))
    return plans
