"""The robot's own side: a velocity command (v, ω) as wheel speeds within the robot's
limits, and the safety rules it keeps whatever the planner does.

**Wheels.** A differential drive of track ``b`` turns a command (v forwards, ω
counter-clockwise) into rim speeds ``v_l = v − ω·b/2``, ``v_r = v + ω·b/2``
(:func:`wheel_targets`): ω first bounded by the top yaw rate, then both rims scaled
down together when one would exceed the top speed (the path's curvature is kept).
Each rim's speed changes by at most the acceleration limit per second
(:func:`ramp`), the braking limit when a safety rule stops the robot.

**Safety** (:class:`RobotBase`, the robot's firmware, on the world's clock): the robot
follows the newest command it received, and brakes to a stop when

* no command came for ``command_timeout_s`` (the watchdog: the planner, its host or the
  network is gone),
* the frame the command was made from is older than ``max_frame_age_s`` (a late
  command about a world that has moved on), or
* the command itself says stop (the planner's safety rules: a stale or unproven frame,
  the camera's source lost, the stream's health not ok, the robot not seen).

It drives again with the next command that passes these rules.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ovis.common.config import NavigationConfig
from ovis.common.physical.drive import TRACK_CM, WHEEL_RADIUS_CM

__all__ = [
    "DriveCommand",
    "DriveLimits",
    "RobotBase",
    "body_velocity",
    "ramp",
    "wheel_targets",
]

FloatArray = NDArray[np.float64]


class DriveLimits(NamedTuple):
    """What a robot can do (cm, s, degrees)."""

    max_speed_cm_s: float
    accel_cm_s2: float
    brake_cm_s2: float
    max_yaw_rate_deg_s: float
    track_cm: float = TRACK_CM
    wheel_radius_cm: float = WHEEL_RADIUS_CM

    @classmethod
    def of(cls, nav: NavigationConfig) -> DriveLimits:
        return cls(nav.max_speed_cm_s, nav.max_accel_cm_s2, nav.brake_cm_s2, nav.max_yaw_rate_deg_s)


def wheel_targets(
    v_cm_s: ArrayLike, omega_deg_s: ArrayLike, limits: DriveLimits
) -> tuple[FloatArray, FloatArray]:
    """Left and right rim speeds (cm/s) carrying out (v, ω) within the limits (module
    docstring)."""
    w = np.radians(
        np.clip(
            np.asarray(omega_deg_s, float), -limits.max_yaw_rate_deg_s, limits.max_yaw_rate_deg_s
        )
    )
    v = np.asarray(v_cm_s, float)
    half = 0.5 * limits.track_cm * w
    left, right = v - half, v + half
    scale = np.maximum(1.0, np.maximum(np.abs(left), np.abs(right)) / limits.max_speed_cm_s)
    return left / scale, right / scale


def body_velocity(
    left_cm_s: ArrayLike, right_cm_s: ArrayLike, limits: DriveLimits
) -> tuple[FloatArray, FloatArray]:
    """The (v cm/s, ω rad/s) of rims turning at these speeds."""
    left, right = np.asarray(left_cm_s, float), np.asarray(right_cm_s, float)
    return 0.5 * (left + right), (right - left) / limits.track_cm


def ramp(current: ArrayLike, target: ArrayLike, step: ArrayLike) -> FloatArray:
    """``current`` moved towards ``target`` by at most ``step``."""
    c = np.asarray(current, float)
    return c + np.clip(np.asarray(target, float) - c, -np.asarray(step), np.asarray(step))


class DriveCommand(NamedTuple):
    """A command as the robot holds it: velocity, the world-clock time (s) of the frame
    it was made from and of its receipt, and why it says stop ("" if it does not)."""

    v_cm_s: float
    omega_deg_s: float
    frame_s: float
    received_s: float
    stop: str = ""


class RobotBase:
    """One robot's firmware (module docstring): commands in, wheel speeds out."""

    def __init__(self, limits: DriveLimits, command_timeout_s: float, max_frame_age_s: float):
        self.limits = limits
        self.timeout_s = command_timeout_s
        self.max_age_s = max_frame_age_s
        self._pending: list[DriveCommand] = []
        self.command: DriveCommand | None = None
        self.rims = np.zeros(2)
        #: why the robot is stopping or stopped ("" while it follows a command)
        self.stopped = "no command yet"
        self.followed = 0  # commands taken
        self.too_old = 0  # commands not followed: made from a frame older than the limit

    @classmethod
    def of(cls, nav: NavigationConfig) -> RobotBase:
        return cls(DriveLimits.of(nav), nav.command_timeout_s, nav.max_frame_age_s)

    def receive(self, command: DriveCommand) -> None:
        """A command received (taken at its ``received_s``)."""
        self._pending.append(command)

    def _take(self, now_s: float) -> None:
        due = [c for c in self._pending if c.received_s <= now_s]
        if not due:
            return
        self._pending = [c for c in self._pending if c.received_s > now_s]
        for c in sorted(due, key=lambda c: c.received_s):
            if now_s - c.frame_s > self.max_age_s:
                self.too_old += 1
            self.followed += 1
            self.command = c

    def _why_stop(self, now_s: float) -> str:
        c = self.command
        if c is None:
            return "no command yet"
        if now_s - c.received_s > self.timeout_s:
            return f"no command for {self.timeout_s:g} s"
        if c.stop:  # the planner's own reason first: its stop may be about an old frame
            return c.stop
        if now_s - c.frame_s > self.max_age_s:
            return f"command's frame older than {self.max_age_s:g} s"
        return ""

    def update(self, now_s: float, dt_s: float) -> tuple[float, float]:
        """The wheels' speeds (rad/s, left and right) for the next ``dt_s`` from
        ``now_s``: the newest command due by then, under the safety rules."""
        self._take(now_s)
        self.stopped = self._why_stop(now_s)
        lim = self.limits
        if self.stopped or self.command is None:
            target = np.zeros(2)
            rate = lim.brake_cm_s2
        else:
            left, right = wheel_targets(self.command.v_cm_s, self.command.omega_deg_s, lim)
            target = np.array([float(left), float(right)])
            rate = lim.accel_cm_s2
        self.rims = ramp(self.rims, target, rate * dt_s)
        left, right = (float(r) / lim.wheel_radius_cm for r in self.rims)
        return left, right

    @property
    def speed_cm_s(self) -> float:
        """The speed the rims are set to (cm/s, forwards positive)."""
        return float(np.mean(self.rims))

    def stop_time_s(self) -> float:
        """How long braking from top speed takes (s)."""
        return self.limits.max_speed_cm_s / self.limits.brake_cm_s2
