"""Inputs of the robot's motion planner (paper §5.2, model-notes §6).

For each obstacle O (centre, radius r_O) and the robot centre R:

* **distance** = |O − R| − r_O: robot centre to obstacle centre minus the obstacle's
  radius (reproduces every distance of the paper's Table 1).
* **angle** = the signed angle, in degrees in (−180, 180], counter-clockwise positive,
  from the *goal direction* to the direction R → O. The goal direction is R → goal, or,
  when a goal reference line is configured, that line's direction (its angle to +X).
  (The paper's angle column cannot be reproduced from its positions by any obvious
  definition; this is the project's documented one.)
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "PlannerInputs",
    "planner_inputs",
    "signed_angle_deg",
    "signed_angle_of",
    "wrap_angle_deg",
    "wrap_deg",
]


class PlannerInputs(NamedTuple):
    """Per obstacle, in the order given: distance (cm) and angle (deg)."""

    distance_cm: NDArray[np.float64]
    angle_deg: NDArray[np.float64]


def signed_angle_deg(from_rad: ArrayLike, to_rad: ArrayLike) -> NDArray[np.float64]:
    """Signed angle from one direction to another, degrees in (−180, 180], CCW positive."""
    return wrap_deg(np.degrees(np.subtract(to_rad, from_rad, dtype=np.float64)))


def signed_angle_of(from_rad: float, to_rad: float) -> float:
    """:func:`signed_angle_deg` of one pair, in plain Python (the same formula): for a
    handful of pairs, array calls cost more than the arithmetic."""
    return wrap_angle_deg(math.degrees(to_rad - from_rad))


def wrap_deg(angle: ArrayLike) -> NDArray[np.float64]:
    """Angles in degrees wrapped to (−180, 180]."""
    wrapped = 180.0 - (180.0 - np.asarray(angle, dtype=np.float64)) % 360.0
    return np.where(wrapped == -180.0, 180.0, wrapped)  # (−180 only by rounding)


def wrap_angle_deg(angle: float) -> float:
    """One angle (deg) wrapped to (−180, 180]: :func:`wrap_deg` in plain Python."""
    wrapped = 180.0 - (180.0 - angle) % 360.0
    return 180.0 if wrapped == -180.0 else wrapped


def planner_inputs(
    robot_xy: ArrayLike,
    obstacles_xyr: ArrayLike,
    *,
    goal_xy: ArrayLike | None = None,
    goal_angle_deg: float | None = None,
) -> PlannerInputs:
    """Distance and angle of each obstacle for the motion planner.

    Parameters
    ----------
    robot_xy : (2,) float, cm
        Robot centre on the floor.
    obstacles_xyr : (N, 3) float, cm
        Obstacle centres and radii.
    goal_xy : (2,) float, cm, optional
        Goal point; the goal direction is robot → goal.
    goal_angle_deg : float, optional
        Direction of the goal reference line (degrees from +X); takes precedence over
        ``goal_xy``. One of the two is required.
    """
    rx, ry = (float(v) for v in np.asarray(robot_xy, dtype=np.float64).reshape(2))
    obs = np.asarray(obstacles_xyr, dtype=np.float64).reshape(-1, 3)
    if not (math.isfinite(rx) and math.isfinite(ry) and (np.abs(obs) < np.inf).all()):
        raise ValueError("robot and obstacle coordinates must be finite numbers")
    if goal_angle_deg is not None:
        if not math.isfinite(goal_angle_deg):
            raise ValueError("goal_angle_deg must be a finite number")
        goal_dir = math.radians(goal_angle_deg)
    elif goal_xy is not None:
        gx, gy = (float(v) for v in np.asarray(goal_xy, dtype=np.float64).reshape(2))
        if not (math.isfinite(gx) and math.isfinite(gy)):
            raise ValueError("goal coordinates must be finite numbers")
        if math.hypot(gx - rx, gy - ry) < 1e-9:
            raise ValueError("the robot is on the goal: the goal direction is undefined")
        goal_dir = math.atan2(gy - ry, gx - rx)
    else:
        raise ValueError("give a goal point or a goal reference-line angle")
    dx, dy = obs[:, 0] - rx, obs[:, 1] - ry
    distance = np.hypot(dx, dy) - obs[:, 2]
    angle = signed_angle_deg(goal_dir, np.arctan2(dy, dx))
    return PlannerInputs(distance, angle)
