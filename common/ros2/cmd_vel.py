"""A robot's velocity command as ROS 2's ``geometry_msgs/msg/TwistStamped`` on
``robots/robot_<id>/cmd_vel`` (under the node's namespace: ``/ovis/robots/robot_3/cmd_vel``),
what a ROS 2 Jazzy ``diff_drive_controller`` follows (its ``use_stamped_vel`` default):
``twist.linear.x`` forwards (m/s), ``twist.angular.z`` counter-clockwise in ROS's
right-handed frame (rad/s; on a mirrored floor, :mod:`ovis.common.ros2.floor`, ovis's
counter-clockwise is ROS's clockwise), the rest 0; the header stamped with the capture
time of the frame the command was made from, ``frame_id`` the robot's base frame
(``robot_<id>/base_link``). A command that says stop is all zeros.

**Read back** (:func:`read_cmd_vel`, the physical world following ``cmd_vel``,
``[navigation] follow = "cmd_vel"``): the same mapping inverted, to ovis's cm/s and
degrees/s counter-clockwise on its floor. Refused, with the reason (:class:`CmdVelError`):
bytes that are not a TwistStamped, a number that is not finite, a velocity a
differential drive cannot have (sideways, vertical, roll or pitch), a ``frame_id`` that
is another robot's, a stamp further ahead of the receiver's clock than the frame-age
limit (its age could not be judged). A speed or turn rate over the robot's limit is
clamped to it (as ``diff_drive_controller``'s limiters do) and said so."""

from __future__ import annotations

import math
import re
from typing import NamedTuple

from ovis.common.ros2.cdr import RosMessage, ros_message, ros_time, typestore

__all__ = [
    "TWIST_STAMPED",
    "CmdVelError",
    "TwistCommand",
    "cmd_vel_message",
    "cmd_vel_robot",
    "cmd_vel_topic",
    "read_cmd_vel",
]

TWIST_STAMPED = "geometry_msgs/msg/TwistStamped"

_TOPIC = re.compile(r"robots/robot_(\d+)/cmd_vel")


class CmdVelError(ValueError):
    """A ``cmd_vel`` message not followed (the reason)."""


class TwistCommand(NamedTuple):
    """A ``cmd_vel`` message in ovis's terms: forwards cm/s, counter-clockwise degrees/s
    on ovis's floor, the header's stamp (ns: the capture time of the frame it was made
    from), and whether a limit clamped it."""

    v_cm_s: float
    omega_deg_s: float
    stamp_ns: int
    clamped: bool = False


def cmd_vel_topic(robot_id: int) -> str:
    """The command's topic, relative to the namespace."""
    return f"robots/robot_{int(robot_id)}/cmd_vel"


def cmd_vel_robot(name: str, namespace: str) -> int | None:
    """The robot a fully qualified topic ``name`` commands, if it is a ``cmd_vel`` topic
    in ``namespace`` (None otherwise)."""
    prefix = namespace.rstrip("/") + "/"
    if not name.startswith(prefix):
        return None
    match = _TOPIC.fullmatch(name[len(prefix) :])
    return None if match is None else int(match.group(1))


def _frame_id(robot_id: int) -> str:
    return f"robot_{int(robot_id)}/base_link"


def cmd_vel_message(
    robot_id: int,
    v_cm_s: float,
    omega_deg_s: float,
    stamp_ns: int,
    *,
    mirrored: bool = False,
) -> RosMessage:
    """The TwistStamped of one command (module docstring)."""
    T = typestore().types
    sec, nanosec = ros_time(stamp_ns)
    header = T["std_msgs/msg/Header"](
        stamp=T["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec),
        frame_id=_frame_id(robot_id),
    )
    sign = -1.0 if mirrored else 1.0

    def vec(x: float, z: float):
        return T["geometry_msgs/msg/Vector3"](x=x, y=0.0, z=z)

    twist = T["geometry_msgs/msg/Twist"](
        linear=vec(v_cm_s / 100.0, 0.0), angular=vec(0.0, sign * math.radians(omega_deg_s))
    )
    message = T[TWIST_STAMPED](header=header, twist=twist)
    return ros_message(TWIST_STAMPED, message, cmd_vel_topic(robot_id), stamp_ns)


def _decode(cdr: bytes):
    try:
        return typestore().deserialize_cdr(cdr, TWIST_STAMPED)
    except Exception as exc:  # rosbags raises what its reader meets: all mean "not one"
        raise CmdVelError(f"not a {TWIST_STAMPED} in CDR ({type(exc).__name__})") from None


def read_cmd_vel(
    cdr: bytes,
    robot_id: int,
    *,
    now_ns: int,
    mirrored: bool,
    max_speed_cm_s: float,
    max_yaw_rate_deg_s: float,
    max_frame_age_s: float,
) -> TwistCommand:
    """One ``cmd_vel`` message for robot ``robot_id`` received at ``now_ns``, in ovis's
    terms, within the robot's limits (module docstring); :class:`CmdVelError` if it is
    not followed."""
    msg = _decode(cdr)
    lin, ang = msg.twist.linear, msg.twist.angular
    values = (lin.x, lin.y, lin.z, ang.x, ang.y, ang.z)
    if not all(math.isfinite(v) for v in values):
        raise CmdVelError("a velocity that is not a finite number")
    if any(v != 0.0 for v in (lin.y, lin.z, ang.x, ang.y)):
        raise CmdVelError(
            "a velocity a differential drive cannot have (linear y or z, angular x or y not 0)"
        )
    frame_id = msg.header.frame_id
    if frame_id not in ("", _frame_id(robot_id)):
        raise CmdVelError(f"frame_id {frame_id!r} is not {_frame_id(robot_id)!r}")
    stamp_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
    ahead_s = (stamp_ns - now_ns) / 1e9
    if ahead_s > max_frame_age_s:
        raise CmdVelError(
            f"stamped {ahead_s:.3g} s ahead of the receiver's clock (over the frame-age "
            f"limit {max_frame_age_s:g} s: its age cannot be judged)"
        )
    sign = -1.0 if mirrored else 1.0
    v = lin.x * 100.0
    omega = sign * math.degrees(ang.z)
    v_in = min(max(v, -max_speed_cm_s), max_speed_cm_s)
    omega_in = min(max(omega, -max_yaw_rate_deg_s), max_yaw_rate_deg_s)
    return TwistCommand(v_in, omega_in, stamp_ns, clamped=(v_in, omega_in) != (v, omega))
