"""What the map draws of each driven robot (issue 37, item 7): its goal, its current
velocity command and its trail as the world reports it, each saying where it comes
from, and a command judged by the robots' own limits so that nothing stale is shown
as current.

A command is *current* while it could still drive the robot: the frame it was made
from is at most ``[navigation] max_frame_age_s`` old and no newer command has been
missing for longer than the robots' watchdog, ``command_timeout_s``; else it is
*stale* and says which limit it is over. A command that tells the robot to stop is
*stop*, with the planner's reason. Ages are on the message's own clock: the wall clock
for a live command, the recording's (its replay mark's time plus the seconds since it
arrived) for a replay.

The goal is the planner's configured goal (``[pose] goal_cm`` or the robot's own), as
its commands carry it, or, before any command, the world's (its drive reports). The
trail is where the world says the robot was (the physics' truth, :class:`RobotDrive`);
the page draws ovis's own estimates beside it from the obstacle messages.
"""

from __future__ import annotations

import collections
import math
from typing import Literal

import msgspec

from ovis.common.config import NavigationConfig
from ovis.common.messages import ReplayMark, RobotCommand, RobotDrive

__all__ = [
    "COMMAND_FROM",
    "GOAL_FROM",
    "TRAIL_KEPT",
    "WORLD_TRAIL_FROM",
    "CommandShown",
    "Drives",
    "RobotShown",
    "command_state",
    "robot_poses",
]

#: World positions kept per robot for its trail.
TRAIL_KEPT = 120

GOAL_FROM = {
    "planner": "configured: the planner's goal ([pose] goal_cm or the robot's own), "
    "as its commands carry it",
    "world": "configured: the world's scenario, as its drive reports carry it",
}
WORLD_TRAIL_FROM = "reported by the simulated world (its physics, not ovis's estimate)"
COMMAND_FROM = {
    "frame": "ovis's estimate of the robot on the frame the command was made from",
    "newest": "ovis's newest estimate of the robot (the command's frame is no longer kept)",
    "world": "where the world reports the robot (ovis has not reported it)",
}

CommandState = Literal["current", "stale", "stop"]


class CommandShown(msgspec.Struct, kw_only=True):
    """A robot's newest command as the page draws it: forwards ``v_cm_s`` and
    counter-clockwise ``omega_deg_s`` in the floor frame; made from the frame captured
    at ``frame_stamp_ns`` (``frame_seq`` when the view still holds that frame's
    obstacle message), ``age_s`` ago on the message's clock; ``since_s`` since it
    arrived; ``state`` and why; the limits it was judged by; and where it is drawn
    from (``at``: x, y cm and heading °; ``at_from`` says whose estimate)."""

    seq: int
    v_cm_s: float
    omega_deg_s: float
    frame_stamp_ns: int
    frame_seq: int | None
    age_s: float
    since_s: float
    state: CommandState
    reason: str
    max_frame_age_s: float
    command_timeout_s: float
    planner: str
    replay: str = ""
    at: tuple[float, float, float] | None = None
    at_from: str = ""


class RobotShown(msgspec.Struct, kw_only=True):
    """One driven robot on the map: goal (cm) and where it comes from, command, the
    world's trail (cm, oldest first) and its last report."""

    id: int
    goal_cm: tuple[float, float] | None = None
    goal_from: str = ""
    command: CommandShown | None = None
    trail_cm: list[tuple[float, float]] = []
    trail_from: str = ""
    goal_reached: bool = False
    collisions: int = 0


def command_state(
    age_s: float, since_s: float, stop: str, nav: NavigationConfig
) -> tuple[CommandState, str]:
    """Whether a command made from a frame ``age_s`` old, received ``since_s`` ago,
    could still drive a robot under ``nav``'s limits (:mod:`ovis.common.navigation.base`),
    and why not."""
    if since_s > nav.command_timeout_s:
        return "stale", (
            f"no newer command for {since_s:.2f} s: over the robots' watchdog of "
            f"{nav.command_timeout_s:g} s ([navigation] command_timeout_s)"
        )
    if age_s > nav.max_frame_age_s:
        return "stale", (
            f"made from a frame {age_s:.2f} s old: over the robots' limit of "
            f"{nav.max_frame_age_s:g} s ([navigation] max_frame_age_s)"
        )
    if stop:
        return "stop", f"the planner says stop: {stop}"
    return "current", ""


class _Heard(msgspec.Struct, kw_only=True):
    """A command as it arrived: the view's monotonic clock then, and its replay mark."""

    received_s: float
    replay: ReplayMark | None


class Drives:
    """The newest command and the recent drive reports of every robot of one arena
    (not thread-safe: the feed holds its lock)."""

    def __init__(self, nav: NavigationConfig) -> None:
        self.nav = nav
        self.commands: dict[int, tuple[RobotCommand, _Heard]] = {}
        self.reports: dict[int, collections.deque[RobotDrive]] = {}

    def command(self, cmd: RobotCommand, received_s: float, replay: ReplayMark | None) -> None:
        """Keep ``cmd`` as its robot's newest (an older one of the same run is ignored)."""
        kept = self.commands.get(cmd.robot_id)
        if kept is not None and kept[0].stream == cmd.stream and kept[0].seq >= cmd.seq:
            return
        self.commands[cmd.robot_id] = (cmd, _Heard(received_s=received_s, replay=replay))

    def drive(self, report: RobotDrive) -> None:
        trail = self.reports.setdefault(report.robot_id, collections.deque(maxlen=TRAIL_KEPT))
        if trail and trail[-1].t_s > report.t_s:  # a new run (a replay again): a new trail
            trail.clear()
        trail.append(report)

    def clear(self) -> None:
        self.commands.clear()
        self.reports.clear()

    def shown(
        self,
        now_ns: int,
        now_s: float,
        frames: dict[int, int],
        poses: dict[int, dict[int, tuple[float, float, float]]],
    ) -> list[RobotShown]:
        """Every robot heard of, as the page draws it now. ``frames``: the kept obstacle
        messages' capture stamp → seq; ``poses``: per seq, ovis's robot poses (id →
        x, y cm, heading °)."""
        out = []
        for rid in sorted(set(self.commands) | set(self.reports)):
            reports = self.reports.get(rid)
            last = reports[-1] if reports else None
            robot = RobotShown(id=rid)
            kept = self.commands.get(rid)
            if kept is not None and kept[0].goal_cm is not None:
                robot.goal_cm, robot.goal_from = kept[0].goal_cm, GOAL_FROM["planner"]
            elif last is not None and last.goal_cm is not None:
                robot.goal_cm, robot.goal_from = last.goal_cm, GOAL_FROM["world"]
            if reports:
                robot.trail_cm = [(r.x_cm, r.y_cm) for r in reports]
                robot.trail_from = WORLD_TRAIL_FROM
                robot.goal_reached, robot.collisions = last.goal_reached, last.collisions
            if kept is not None:
                robot.command = self._command(*kept, now_ns, now_s, frames, poses, last)
            out.append(robot)
        return out

    def _command(
        self,
        cmd: RobotCommand,
        heard: _Heard,
        now_ns: int,
        now_s: float,
        frames: dict[int, int],
        poses: dict[int, dict[int, tuple[float, float, float]]],
        last: RobotDrive | None,
    ) -> CommandShown:
        since_s = max(0.0, now_s - heard.received_s)
        if heard.replay is None:
            clock_ns = now_ns
        else:  # the recording's clock: the command's own time in it, and the time since
            clock_ns = heard.replay.recorded_ns + round(since_s * 1e9)
        age_s = (clock_ns - cmd.stamp_ns) / 1e9
        state, reason = command_state(age_s, since_s, cmd.stop, self.nav)
        seq = frames.get(cmd.stamp_ns)
        at, at_from = None, ""
        if seq is not None and cmd.robot_id in poses.get(seq, {}):
            at, at_from = poses[seq][cmd.robot_id], COMMAND_FROM["frame"]
        elif poses and cmd.robot_id in poses[max(poses)]:
            at, at_from = poses[max(poses)][cmd.robot_id], COMMAND_FROM["newest"]
        elif last is not None:
            at, at_from = (last.x_cm, last.y_cm, last.heading_deg), COMMAND_FROM["world"]
        return CommandShown(
            seq=cmd.seq,
            v_cm_s=cmd.v_cm_s,
            omega_deg_s=cmd.omega_deg_s,
            frame_stamp_ns=cmd.stamp_ns,
            frame_seq=seq,
            age_s=age_s,
            since_s=since_s,
            state=state,
            reason=reason,
            max_frame_age_s=self.nav.max_frame_age_s,
            command_timeout_s=self.nav.command_timeout_s,
            planner=cmd.planner,
            replay="" if heard.replay is None else heard.replay.recording,
            at=at,
            at_from=at_from,
        )


def robot_poses(message: dict) -> dict[int, tuple[float, float, float]]:
    """ovis's marked robots of a decoded obstacle message: id → (x, y cm, heading °)."""
    out = {}
    for r in message.get("robots") or []:
        try:
            x, y, h = float(r["x_cm"]), float(r["y_cm"]), float(r["heading_deg"])
            rid = int(r["id"])
        except (KeyError, TypeError, ValueError):
            continue
        if all(math.isfinite(v) for v in (x, y, h)):
            out[rid] = (x, y, h)
    return out
