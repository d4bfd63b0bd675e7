"""The most critical obstacle and its planner inputs (paper §5.2, in the way of
Pratihar, Deb & Ghosh 1999).

Each other body (obstacle or robot) is taken where it will be ``lookahead_s`` from now
at its measured velocity (its predicted position: the robot plans against where things
are going, not where they were); or, for a controller that asks for it (``closest``),
where it will be nearest to the robot within ``lookahead_s``, both moving on at their
velocities (the body's place relative to the robot at that instant: a body crossing
the robot's way is taken where it crosses, not past it). Of those, the ones that
matter are

* ahead: within ±90° of the robot's goal direction or of its heading, or
* near: within ``NEAR_CM`` of the robot's own radius (whatever their side),

and the most critical is the nearest of them. Its inputs are the paper's
(:func:`ovis.common.world.planner.planner_inputs`, computed here for B robots at once):
**distance** ``|O − R| − r_O`` (cm) and **angle** from the goal direction to R → O
(degrees, counter-clockwise positive, in (−180, 180]). A robot with none gets no
obstacle (``index`` −1).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from ovis.common.navigation.observe import Situation
from ovis.common.navigation.steering import goal_direction, wrap_rad

__all__ = ["FRONT_DEG", "NEAR_CM", "Critical", "critical_obstacle"]

#: Half-angle of the sector ahead (deg), and the range all round (cm beyond the robot).
FRONT_DEG = 90.0
NEAR_CM = 12.0


class Critical(NamedTuple):
    """Per robot: the index of its most critical body (−1: none) and its inputs."""

    index: NDArray[np.int64]
    distance_cm: NDArray[np.float64]
    angle_deg: NDArray[np.float64]


def critical_obstacle(
    s: Situation,
    lookahead_s: float | NDArray[np.float64],
    closest: bool | NDArray[np.bool_] = False,
) -> Critical:
    """Each robot's most critical body and its paper inputs (module docstring;
    ``lookahead_s`` and ``closest`` per robot or for all)."""
    tau = np.asarray(lookahead_s, float).reshape(-1, 1) if np.ndim(lookahead_s) else lookahead_s
    dx = s.ox + s.ovx * tau - s.x[:, None]
    dy = s.oy + s.ovy * tau - s.y[:, None]
    if np.any(closest):
        rx, ry = s.ox - s.x[:, None], s.oy - s.y[:, None]
        wx = s.ovx - (s.speed * np.cos(s.heading))[:, None]
        wy = s.ovy - (s.speed * np.sin(s.heading))[:, None]
        with np.errstate(divide="ignore", invalid="ignore"):
            t_min = np.clip(np.nan_to_num(-(rx * wx + ry * wy) / (wx * wx + wy * wy)), 0.0, tau)
        use = np.asarray(closest, bool).reshape(-1, 1)
        dx = np.where(use, rx + wx * t_min, dx)
        dy = np.where(use, ry + wy * t_min, dy)
    distance = np.hypot(dx, dy) - s.orad
    bearing = np.arctan2(dy, dx)
    to_goal, _ = goal_direction(s)
    angle = np.degrees(wrap_rad(bearing - to_goal[:, None]))
    off_heading = np.degrees(np.abs(wrap_rad(bearing - s.heading[:, None])))
    ahead = (np.abs(angle) <= FRONT_DEG) | (off_heading <= FRONT_DEG)
    near = distance <= s.radius[:, None] + NEAR_CM
    candidate = s.present & (ahead | near)
    masked = np.where(candidate, distance, np.inf)
    b = np.arange(s.x.size)
    if masked.shape[1] == 0:
        none = np.full(s.x.size, -1)
        return Critical(none, np.full(s.x.size, np.inf), np.zeros(s.x.size))
    k = np.argmin(masked, axis=1)
    found = np.isfinite(masked[b, k])
    angle_k = np.where(angle[b, k] == -180.0, 180.0, angle[b, k])
    return Critical(
        np.where(found, k, -1),
        np.where(found, distance[b, k], np.inf),
        np.where(found, angle_k, 0.0),
    )
