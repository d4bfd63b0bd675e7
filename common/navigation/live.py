"""The planner's side of live driving (``ovis run planner``): one command per robot with
a goal on every proven obstacle frame, and the rules that make it say stop.

A robot's goal is its ``[[pose.robots]] goal_cm``, else ``[pose] goal_cm`` (the
arena's one goal). On each obstacle frame (the pose stage's, already proven by its
signature: an unproven one never reaches here) each such robot gets a command from
its own :class:`~ovis.common.navigation.planners.Planner`, unless a rule says stop:

* the frame is older than ``[navigation] max_frame_age_s`` when it is planned on
  (capture → now, the bus's clock: a stale frame);
* the stream's health, as the pose stage last published it (``ovis/<arena>/health``,
  signed), is not ok: stalled, degraded, failing, or the camera's source lost (the
  pose stage says so at once when the capture reports it);
* the robot's marker was not seen for longer than ``[navigation] predict_s`` (the
  pose filter's prediction is driven on that long: an obstacle touching the robot
  merges their blobs for a frame or two).

A stop is still a command (v = ω = 0, ``stop`` saying why), so that the robot brakes
at once instead of waiting for its watchdog; the watchdog remains for when no command
comes at all.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

from ovis.common.config import OvisConfig
from ovis.common.navigation.fuzzy import FuzzyParams
from ovis.common.navigation.observe import observe_detection
from ovis.common.navigation.planners import BRAKE, Command, make_planner
from ovis.common.world.detection import DetectedObject
from ovis.common.world.robots import RobotState

__all__ = ["LivePlanner", "Order", "goals_of"]


class Order(NamedTuple):
    """One robot's command of one frame, and why it says stop ("" if it does not)."""

    robot_id: int
    goal_cm: tuple[float, float]
    command: Command
    stop: str = ""


def goals_of(config: OvisConfig) -> dict[int, tuple[float, float]]:
    """Each configured robot's goal (its own, else the arena's; module docstring)."""
    arena = config.pose.goal_cm
    goals = {}
    for robot in config.pose.robots:
        goal = robot.goal_cm if robot.goal_cm is not None else arena
        if goal is not None:
            goals[robot.id] = (float(goal[0]), float(goal[1]))
    return goals


_HALT = Command(0.0, 0.0, False)


class LivePlanner:
    """Every robot's planner on the live frames (module docstring)."""

    def __init__(self, config: OvisConfig, name: str, fuzzy: FuzzyParams | None) -> None:
        self.config = config
        self.goals = goals_of(config)
        self.planners = {i: make_planner(name, config, fuzzy) for i in self.goals}
        self.max_age_s = config.navigation.max_frame_age_s
        self.predict_s = config.navigation.predict_s
        self.health = "waiting"
        self.health_reason = ""

    def on_health(self, state: str, reason: str = "") -> None:
        """The stream's health as the pose stage last said it."""
        self.health, self.health_reason = state, reason

    def _why_stop(self, age_s: float) -> str:
        if self.health not in ("ok", "waiting"):
            why = f": {self.health_reason}" if self.health_reason else ""
            return f"stream health {self.health}{why}"
        if age_s > self.max_age_s:
            return f"frame {age_s:.2f} s old (limit {self.max_age_s:g} s)"
        return ""

    def plan(
        self,
        robots: Sequence[RobotState],
        obstacles: Sequence[DetectedObject],
        frame_s: float,
        now_s: float,
    ) -> list[Order]:
        """The orders of one obstacle frame captured at ``frame_s`` and planned on at
        ``now_s`` (s, the same clock)."""
        general = self._why_stop(now_s - frame_s)
        out = []
        for ident, goal in self.goals.items():
            if general:
                out.append(Order(ident, goal, _HALT, general))
                continue
            obs = observe_detection(robots, obstacles, ident, goal, frame_s, self.predict_s)
            if obs is None:
                out.append(Order(ident, goal, _HALT, "robot not seen"))
                continue
            command = self.planners[ident].plan(obs)
            out.append(Order(ident, goal, command, BRAKE if command.brake else ""))
        return out
