"""From a wanted heading and speed to a velocity command (v, ω), the same for every
planner: turn towards the heading at ``HEADING_GAIN`` per second of error (within the
top yaw rate), drive at the speed times the cosine of the error (turning on the spot
when facing more than 90° away), never faster than stopping at the goal allows
(``v ≤ √(2·a·d)``, ``d`` the distance to the goal less half its tolerance), and stop at
the goal (within its tolerance). Within ``EDGE_CM`` of an edge of the arena (beyond its
radius; a planner may set its own band) a robot is not sent further out: the wanted
heading loses its outward part, so it runs along the edge (the camera sees the arena; a
robot beyond it is lost); in a corner, where nothing of it is left, the goal's
direction is taken the same way. A planner may also ask that the speed goes with the
heading the edge took away (``edge_slow``: 0 keeps the speed, 1 scales it by the
cosine of the angle taken away): a robot that cannot turn where it wanted to need not
run along the edge at the speed it chose for that turn.

**The way round** (:class:`Turns`, kept per robot between frames). A heading nearly
behind the robot is as near one way round as the other, and the frame-to-frame noise
of the wanted heading (or of the robot's own) flips the sign of the error: a control
without memory then turns the robot at the top yaw rate one way and back the next
frame, so that it neither turns round nor stays put (MuJoCo seed 317,
docs/navigation.md). So where the error is within ``HOLD_DEG`` of a half turn, the
robot keeps turning the way it turned the frame before, even when the other way is
shorter (by up to twice ``HOLD_DEG``). It turns the other way when the error on that
side is below ``180° − HOLD_DEG`` (the wanted heading moved decisively), and as a turn
brings the error down, that is the shorter way anyway."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ovis.common.navigation.base import DriveLimits
from ovis.common.navigation.observe import Situation

__all__ = [
    "EDGE_CM",
    "HEADING_GAIN",
    "HOLD_DEG",
    "Arena",
    "Steer",
    "Turns",
    "goal_direction",
    "held",
    "inside",
    "steer",
    "wrap_rad",
]

#: Turn rate per radian of heading error (1/s).
HEADING_GAIN = 3.0
#: How near an arena's edge (cm, beyond the robot's radius) a robot is kept from
#: heading further out.
EDGE_CM = 4.0
#: The robot brakes to stop at this share of the goal's tolerance, so that it crosses
#: into the tolerance still moving (braking to its edge would take ever longer).
ARRIVE_SHARE = 0.5
#: Within this (deg) of a half turn a robot keeps the way it turned before.
HOLD_DEG = 45.0

FloatArray = NDArray[np.float64]


class Arena(NamedTuple):
    """The floor the robots must stay on (cm)."""

    x0: float
    x1: float
    y0: float
    y1: float


class Steer(NamedTuple):
    """Commands of B robots: v (cm/s), ω (deg/s), which are at their goal, and which
    say brake (a stop at the robot's braking limit, :mod:`.guard`; None: none)."""

    v_cm_s: FloatArray
    omega_deg_s: FloatArray
    arrived: NDArray[np.bool_]
    brake: NDArray[np.bool_] | None = None


def wrap_rad(a: ArrayLike) -> FloatArray:
    """Angles wrapped to [−π, π)."""
    return (np.asarray(a, float) + np.pi) % (2.0 * np.pi) - np.pi


def held(error: ArrayLike, way: ArrayLike) -> FloatArray:
    """Heading errors (rad, wrapped) taken the way round ``way`` (+1 counter-clockwise,
    −1 clockwise, 0 either) where they lie within :data:`HOLD_DEG` of a half turn
    (module docstring): there an error of the other sign goes the long way, by up to
    π + ``HOLD_DEG``."""
    error = np.asarray(error, float)
    way = np.asarray(way, float)
    behind = np.abs(error) > np.pi - np.radians(HOLD_DEG)
    return np.where(behind & (way * error < 0.0), error + 2.0 * np.pi * way, error)


class Turns:
    """Each robot's way round (module docstring), kept between frames: +1
    counter-clockwise, −1 clockwise, 0 not yet turned; and the heading (rad) it was
    steered to (NaN: none yet), which its guard keeps to (:mod:`.guard`). One per set of
    robots."""

    def __init__(self) -> None:
        self.way = np.zeros(0)
        self.heading = np.zeros(0)

    def current(self, n: int) -> tuple[FloatArray, FloatArray]:
        """The ways and last headings of ``n`` robots (none when the set changed size)."""
        if self.way.shape != (n,):
            self.way, self.heading = np.zeros(n), np.full(n, np.nan)
        return self.way, self.heading

    def hold(self, error: ArrayLike, heading: ArrayLike) -> FloatArray:
        """The errors (rad, wrapped; (B,)) to steer by towards ``heading`` (rad), each
        kept its robot's way round (:func:`held`); each robot's way becomes the sign of
        its error taken, its last heading ``heading``."""
        error = np.asarray(error, float)
        way, _ = self.current(error.size)
        taken = held(error, way)
        self.way = np.where(taken != 0.0, np.sign(taken), way)
        self.heading = np.broadcast_to(np.asarray(heading, float), error.shape).copy()
        return taken


def goal_direction(s: Situation) -> tuple[FloatArray, FloatArray]:
    """Direction (rad) and distance (cm) from each robot to its goal."""
    dx, dy = s.goal_x - s.x, s.goal_y - s.y
    return np.arctan2(dy, dx), np.hypot(dx, dy)


def _inward(
    s: Situation, h: FloatArray, arena: Arena, edge_cm: ArrayLike = EDGE_CM
) -> tuple[FloatArray, FloatArray]:
    """The unit vector of ``h`` without its outward part near an edge (module docstring)."""
    hx, hy = np.cos(h), np.sin(h)
    reach = s.radius + np.asarray(edge_cm, float)
    hx = np.where(
        (s.x - reach <= arena.x0) & (hx < 0) | (s.x + reach >= arena.x1) & (hx > 0), 0.0, hx
    )
    hy = np.where(
        (s.y - reach <= arena.y0) & (hy < 0) | (s.y + reach >= arena.y1) & (hy > 0), 0.0, hy
    )
    return hx, hy


def inside(
    s: Situation, heading: ArrayLike, arena: Arena, edge_cm: ArrayLike = EDGE_CM
) -> FloatArray:
    """``heading`` (rad) without its outward part where a robot is within ``edge_cm``
    (beyond its radius) of an edge of ``arena`` (module docstring). Where nothing is
    left (in a corner, heading out of both edges) the goal direction is taken so, the
    way out of the corner that leads on; a robot kept on the wanted heading there would
    leave the arena, and the camera's view."""
    h = np.asarray(heading, float)
    hx, hy = _inward(s, h, arena, edge_cm)
    to_goal, _ = goal_direction(s)
    gx, gy = _inward(s, np.broadcast_to(to_goal, h.shape), arena, edge_cm)
    stuck = (hx == 0.0) & (hy == 0.0)
    lost = stuck & (gx == 0.0) & (gy == 0.0)
    wanted = np.arctan2(np.where(stuck, gy, hy), np.where(stuck, gx, hx))
    return np.where(lost, h, wanted)


def steer(
    s: Situation,
    heading: ArrayLike,
    speed: ArrayLike,
    limits: DriveLimits,
    tolerance_cm: float,
    arena: Arena | None = None,
    edge_cm: ArrayLike = EDGE_CM,
    edge_slow: ArrayLike = 0.0,
    turns: Turns | None = None,
) -> Steer:
    """The commands that take each robot towards ``heading`` (rad) at ``speed`` (cm/s),
    kept on ``arena`` if given, within ``edge_cm`` of its edges, slowed by
    ``edge_slow`` where the edge takes some of the heading away, each turning its way
    round kept in ``turns`` (None: the shorter way, afresh each frame) (module
    docstring)."""
    if arena is not None:
        wanted = np.asarray(heading, float)
        heading = inside(s, wanted, arena, edge_cm)
        kept = np.maximum(np.cos(wrap_rad(heading - wanted)), 0.0)
        speed = np.asarray(speed, float) * (1.0 - np.asarray(edge_slow, float) * (1.0 - kept))
    error = wrap_rad(np.asarray(heading, float) - s.heading)
    if turns is not None:
        error = turns.hold(error, heading)
    omega = np.clip(
        np.degrees(HEADING_GAIN * error), -limits.max_yaw_rate_deg_s, limits.max_yaw_rate_deg_s
    )
    _, distance = goal_direction(s)
    room = np.maximum(distance - ARRIVE_SHARE * tolerance_cm, 0.0)
    v = np.minimum(np.asarray(speed, float), limits.max_speed_cm_s) * np.maximum(np.cos(error), 0.0)
    v = np.minimum(v, np.sqrt(2.0 * limits.accel_cm_s2 * room))
    arrived = distance <= tolerance_cm
    return Steer(np.where(arrived, 0.0, v), np.where(arrived, 0.0, omega), arrived)
