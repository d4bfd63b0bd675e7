"""What a robot's planner is given in one frame, from ovis's detections or from the
physics truth (the oracle), and many such views as arrays for the batched planners.

An :class:`Observation` is one robot's view: its pose and speed, its goal, its radius
(the configured one, ``[[pose.robots]] radius_cm``: what the planner keeps clear of
others), and every other body — the obstacles and the other robots, each a disk of the
radius ovis reports (equal floor area) moving at its measured velocity (0 until it is
measured). A :class:`Situation` holds B views as (B,) and (B, M) arrays (absent bodies
masked), which is what the planners compute on.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from ovis.common.sim.arena import FrameTruth
from ovis.common.world.detection import DetectedObject
from ovis.common.world.robots import RobotState

__all__ = [
    "Body",
    "Observation",
    "Situation",
    "observe_detection",
    "observe_truth",
    "situation",
]

FloatArray = NDArray[np.float64]


class Body(NamedTuple):
    """Another body as the robot sees it: id, kind, centre (cm), radius (cm), velocity
    (cm/s)."""

    id: int
    kind: str
    x_cm: float
    y_cm: float
    radius_cm: float
    vx_cm_s: float = 0.0
    vy_cm_s: float = 0.0


class Observation(NamedTuple):
    """One robot's view of one frame (module docstring); ``t_s`` the frame's time."""

    t_s: float
    robot_id: int
    x_cm: float
    y_cm: float
    heading_deg: float
    speed_cm_s: float
    radius_cm: float
    goal_cm: tuple[float, float]
    others: list[Body]


class Situation(NamedTuple):
    """B observations as arrays: the robots (B,), the other bodies (B, M) with
    ``present`` saying which are there and ``robot`` which are robots (None: none)."""

    x: FloatArray
    y: FloatArray
    heading: FloatArray  # rad
    speed: FloatArray
    radius: FloatArray
    goal_x: FloatArray
    goal_y: FloatArray
    ox: FloatArray
    oy: FloatArray
    ovx: FloatArray
    ovy: FloatArray
    orad: FloatArray
    present: NDArray[np.bool_]
    robot: NDArray[np.bool_] | None = None


def situation(observations: Sequence[Observation]) -> Situation:
    """The observations as one :class:`Situation` (bodies padded to the most seen)."""
    b = len(observations)
    m = max((len(o.others) for o in observations), default=0)
    table = np.zeros((5, b, m))
    present = np.zeros((b, m), dtype=bool)
    robot = np.zeros((b, m), dtype=bool)
    for i, o in enumerate(observations):
        for j, body in enumerate(o.others):
            table[:, i, j] = body.x_cm, body.y_cm, body.vx_cm_s, body.vy_cm_s, body.radius_cm
            present[i, j] = True
            robot[i, j] = body.kind == "robot"
    rows = np.array(
        [
            [o.x_cm, o.y_cm, math.radians(o.heading_deg), o.speed_cm_s, o.radius_cm, *o.goal_cm]
            for o in observations
        ]
    ).reshape(b, 7)
    return Situation(*rows.T.copy(), *table, present, robot)


def observe_truth(
    truth: FrameTruth,
    robot_id: int,
    goal_cm: tuple[float, float],
    radius_cm: float,
    radii: dict[int, float] | None = None,
    t_s: float = 0.0,
) -> Observation | None:
    """Robot ``robot_id``'s view from the physics truth (None: not in it). ``radii``:
    the planner radius of the other robots (their configured ones; else the truth's)."""
    me = next((o for o in truth.objects if o.kind == "robot" and o.id == robot_id), None)
    if me is None:
        return None
    heading = math.radians(me.heading_deg)
    speed = me.vx_cm_s * math.cos(heading) + me.vy_cm_s * math.sin(heading)
    others = [
        Body(
            o.id,
            o.kind,
            o.x_cm,
            o.y_cm,
            (radii or {}).get(o.id, o.radius_cm) if o.kind == "robot" else o.radius_cm,
            o.vx_cm_s,
            o.vy_cm_s,
        )
        for o in truth.objects
        if o is not me
    ]
    return Observation(
        t_s, robot_id, me.x_cm, me.y_cm, me.heading_deg, speed, radius_cm, goal_cm, others
    )


def observe_detection(
    robots: Sequence[RobotState],
    objects: Sequence[DetectedObject],
    robot_id: int,
    goal_cm: tuple[float, float],
    t_s: float = 0.0,
    max_age_s: float = 0.0,
) -> Observation | None:
    """Robot ``robot_id``'s view from ovis's detection of a frame (a
    :class:`~ovis.common.world.detection.Detection`'s or an obstacle message's
    ``robots`` and ``objects``/``obstacles``); None when its marker was not seen within
    ``max_age_s`` (the pose filter predicts a robot for a while: a planner does not
    drive on a prediction)."""
    me = next((r for r in robots if r.id == robot_id), None)
    if me is None or me.age_s > max_age_s:
        return None
    heading = math.radians(me.heading_deg)
    speed = me.vx_cm_s * math.cos(heading) + me.vy_cm_s * math.sin(heading)
    others = [
        Body(r.id, "robot", r.x_cm, r.y_cm, r.radius_cm, r.vx_cm_s, r.vy_cm_s)
        for r in robots
        if r.id != robot_id
    ]
    others += [
        Body(
            o.id,
            "obstacle",
            o.x_cm,
            o.y_cm,
            o.radius_cm,
            o.vx_cm_s if o.velocity_measured else 0.0,
            o.vy_cm_s if o.velocity_measured else 0.0,
        )
        for o in objects
        if o.kind == "obstacle"
    ]
    return Observation(
        t_s, robot_id, me.x_cm, me.y_cm, me.heading_deg, speed, me.radius_cm, goal_cm, others
    )
