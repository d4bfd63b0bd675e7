"""The unmarked robot over frames: a heading that does not flip, a measured velocity.

A symmetric robot (a rectangle with no marker) shows only its long axis in one frame:
its heading is that axis or the axis turned by 180°. :class:`UnmarkedRobot` tells the two
apart from its motion and, while the motion says nothing, from continuity:

* **Motion**: the direction of the last :data:`TRAVEL_CM` the robot travelled (from the
  latest earlier position at least that far from the current one; each stretch of
  the path tells once). When it lies within
  :data:`ALONG_AXIS_DEG` of the axis, the heading is the end of the axis it points to,
  and the heading is *resolved*: the robot is taken to drive forwards (a robot backing
  up is shown turned round while it does).
* **Continuity**: otherwise the end of the axis nearer the last heading, so the heading
  never jumps by 180° between frames unless the robot's motion says it turned round.
  Until the first motion it is not resolved (``heading_resolved`` false): one of the
  two ends, kept from frame to frame.

The velocity comes from the marked robots' constant-velocity Kalman filter
(:class:`~ovis.common.world.robots.RobotFilter`, ``[pose.filter]``) fed the blob's centre
at each frame's capture time; a turn sharper than :data:`SHARP_TURN_DEG` between two
frames restarts its velocity from that frame's step. A robot not seen for
``pose.robot_timeout_s``, or found further than ``pose.track_gate_cm`` from where its
filter expects it, starts a new track, not resolved.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field
from typing import NamedTuple

from ovis.common.config import PoseConfig
from ovis.common.world.planner import wrap_angle_deg
from ovis.common.world.robots import RobotFilter

__all__ = [
    "ALONG_AXIS_DEG",
    "SHARP_TURN_DEG",
    "TRAVEL_CM",
    "RobotMotion",
    "UnmarkedRobot",
    "axis_end",
]

#: The motion that orients the heading: the last this many cm travelled (well above the
#: noise of a blob's centre, below what a robot covers in a few frames).
TRAVEL_CM = 1.0

#: The motion orients the heading only when it is this close to the axis (a sideways
#: drift says nothing about which end is the front).
ALONG_AXIS_DEG = 45.0

#: A heading that turned by more than this between two frames (a sharp turn, or the
#: robot turning round) restarts the filter's velocity from that frame's step: the
#: constant-velocity model would otherwise lag behind it for several frames.
SHARP_TURN_DEG = 30.0

#: Positions kept to look back along the robot's path for :data:`TRAVEL_CM` of travel.
PATH_FRAMES = 300


class RobotMotion(NamedTuple):
    """The unmarked robot in one frame: heading (deg, None for a round blob), whether it
    is resolved, velocity (cm/s) and whether that is measured (seen at two capture times
    on this track)."""

    heading_deg: float | None
    resolved: bool
    vx_cm_s: float
    vy_cm_s: float
    velocity_measured: bool = False


def axis_end(axis_deg: float, towards_deg: float) -> float:
    """The direction along the axis ``axis_deg`` (either end) nearer ``towards_deg``."""
    if abs(wrap_angle_deg(axis_deg - towards_deg)) <= 90.0:
        return wrap_angle_deg(axis_deg)
    return wrap_angle_deg(axis_deg + 180.0)


class _Path:
    """The robot's recent positions (at most :data:`PATH_FRAMES`) and a box around them
    (never smaller than they span): a robot standing still is seen not to have
    travelled :data:`TRAVEL_CM` from the box alone, without walking its path."""

    def __init__(self) -> None:
        self.points: deque[tuple[float, float]] = deque(maxlen=PATH_FRAMES)
        self._box: tuple[float, float, float, float] | None = None  # x0, y0, x1, y1

    def clear(self) -> None:
        self.points.clear()
        self._box = None

    def append(self, x: float, y: float) -> None:
        self.points.append((x, y))
        self._grow(x, y)

    def _grow(self, x: float, y: float) -> None:
        b = self._box
        self._box = (
            (x, y, x, y) if b is None else (min(b[0], x), min(b[1], y), max(b[2], x), max(b[3], y))
        )

    def travel(self, x: float, y: float) -> float | None:
        """Direction (deg) from the latest position at least :data:`TRAVEL_CM` away to
        (x, y), the path up to that position then forgotten; None if there is none."""
        b = self._box
        if b is None:
            return None
        far_x, far_y = max(x - b[0], b[2] - x), max(y - b[1], b[3] - y)
        if math.hypot(far_x, far_y) < TRAVEL_CM:  # every position is nearer
            return None
        path = self.points
        for k in range(len(path) - 1, -1, -1):
            px, py = path[k]
            if math.hypot(x - px, y - py) >= TRAVEL_CM:
                for _ in range(k + 1):
                    path.popleft()
                self._box = None
                for q in path:
                    self._grow(*q)
                return math.degrees(math.atan2(y - py, x - px))
        return None


@dataclass
class UnmarkedRobot:
    """The track of the one unmarked robot (see the module docstring)."""

    pose: PoseConfig
    heading_deg: float | None = None
    resolved: bool = False
    _filter: RobotFilter | None = None
    _last: tuple[float, float, float] = (0.0, 0.0, 0.0)  # the last frame's x, y, stamp
    _path: _Path = field(default_factory=_Path)

    def update(self, x: float, y: float, axis_deg: float | None, stamp_s: float) -> RobotMotion:
        """Fold in the robot's blob of one frame: its centre (cm), its long axis (deg,
        either end; None when round) and the frame's capture time (s)."""
        f = self._filter
        if f is not None:
            f.predict(stamp_s)
            gone = stamp_s - f.seen_s > self.pose.robot_timeout_s
            if gone or math.hypot(x - f.value[0], y - f.value[1]) > self.pose.track_gate_cm:
                f = None
        if f is None:
            f = self._filter = RobotFilter.start(self.pose, x, y, 0.0, stamp_s)
            self._path.clear()
            self.heading_deg, self.resolved = None, False
        else:
            f.update(x, y, None)
        motion = self._motion(x, y)
        if axis_deg is not None:
            before = self.heading_deg
            if motion is not None and _along(axis_deg, motion):
                self.heading_deg, self.resolved = axis_end(axis_deg, motion), True
            elif before is not None:
                self.heading_deg = axis_end(axis_deg, before)
            else:
                self.heading_deg = wrap_angle_deg(axis_deg)
            turn = 0.0 if before is None else abs(wrap_angle_deg(self.heading_deg - before))
            if turn > SHARP_TURN_DEG:  # no constant-velocity motion: restart
                f = self._restart_velocity(x, y, stamp_s)
        self._path.append(x, y)
        self._last = (x, y, stamp_s)
        heading = None if axis_deg is None else self.heading_deg
        resolved = self.resolved and heading is not None
        return RobotMotion(heading, resolved, f.rate[0], f.rate[1], f.rate_measured)

    def _restart_velocity(self, x: float, y: float, stamp_s: float) -> RobotFilter:
        """A new filter from the previous frame's position, updated with this one: its
        velocity is this frame's step, not the velocity before the turn."""
        px, py, then = self._last
        f = self._filter = RobotFilter.start(self.pose, px, py, 0.0, then)
        f.predict(stamp_s)
        f.update(x, y, None)
        return f

    def _motion(self, x: float, y: float) -> float | None:
        """Direction (deg) from the latest earlier position at least :data:`TRAVEL_CM`
        away to (x, y), the path up to that position then forgotten (a travel tells
        once: a robot that stopped, then turns in place, is not oriented by how it
        came); None if the robot has not travelled that far since."""
        return self._path.travel(x, y)


def _along(axis_deg: float, direction_deg: float) -> bool:
    """Whether a direction lies within :data:`ALONG_AXIS_DEG` of the axis (either end)."""
    off = abs(wrap_angle_deg(direction_deg - axis_deg))
    return min(off, 180.0 - off) <= ALONG_AXIS_DEG
