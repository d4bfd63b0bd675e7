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
from ovis.common.world.planner import signed_angle_of
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


def _goal_directions(robots: list[RobotState], pose: PoseConfig) -> list[float]:
    """Each robot's goal direction (deg from +X); NaN without a goal or on it."""
    specs = {r.id: r for r in pose.robots}
    out = [math.nan] * len(robots)
    for k, robot in enumerate(robots):
        spec = specs.get(robot.id)
        own = spec is not None and (spec.goal_cm is not None or spec.goal_angle_deg is not None)
        goal_xy = spec.goal_cm if own else pose.goal_cm  # type: ignore[union-attr]
        goal_angle = spec.goal_angle_deg if own else pose.goal_angle_deg  # type: ignore[union-attr]
        if goal_angle is not None:
            out[k] = goal_angle
        elif goal_xy is not None:
            dx, dy = goal_xy[0] - robot.x_cm, goal_xy[1] - robot.y_cm
            if math.hypot(dx, dy) >= 1e-9:
                out[k] = math.degrees(math.atan2(dy, dx))
    return out


def robot_plans(
    robots: list[RobotState],
    obstacle_ids: NDArray[np.int64],
    obstacles_xyr: NDArray[np.float64],
    pose: PoseConfig,
) -> list[RobotPlan]:
    """Planner inputs of each robot against the obstacles (ids, (n, 3) x, y, r in cm)
    and the other robots (the paper's formulas, as
    :func:`ovis.common.world.planner.planner_inputs`)."""
    if not robots:
        return []
    goal = _goal_directions(robots, pose)
    # a handful of robots and targets a frame: plain Python per (robot, target) pair
    # costs less than the array calls would
    obstacles = np.asarray(obstacles_xyr, dtype=np.float64).reshape(-1, 3).tolist()
    targets = [*obstacles, *([r.x_cm, r.y_cm, r.radius_cm] for r in robots)]
    ids = [*np.asarray(obstacle_ids).tolist(), *(r.id for r in robots)]
    m = len(obstacles)
    plans = []
    for k, robot in enumerate(robots):
        x, y, heading = robot.x_cm, robot.y_cm, math.radians(robot.heading_deg)
        has_goal = not math.isnan(goal[k])
        to_goal = math.radians(goal[k])
        entries = []
        for c, (tx, ty, radius) in enumerate(targets):
            if c == m + k:  # not itself
                continue
            dx, dy = tx - x, ty - y
            direction = math.atan2(dy, dx)
            entries.append(
                TargetEntry(
                    target_id=ids[c],
                    target_kind="obstacle" if c < m else "robot",
                    distance_cm=math.hypot(dx, dy) - radius,
                    angle_deg=signed_angle_of(to_goal, direction) if has_goal else None,
                    heading_angle_deg=signed_angle_of(heading, direction),
                )
            )
        plans.append(
            RobotPlan(
                robot_id=robot.id, goal_direction_deg=goal[k] if has_goal else None, entries=entries
            )
        )
    return plans
