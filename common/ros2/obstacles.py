"""An ovis obstacle frame as ROS 2 messages: PoseArray, MarkerArray and one Odometry per
robot (see :mod:`ovis.common.ros2.convert` for what each holds).

They go out with every frame, so a frame costs only what changes: each thread keeps its
message objects (rosbags' typestore classes) between frames and rewrites their fields in
place before rosbags serialises them, instead of building a tree of nested objects per
message; what never changes (colours, the empty texture and mesh, lifetimes) is built
once and shared. The objects never leave this module: the caller gets CDR bytes.
"""

from __future__ import annotations

import functools
import math
import threading
from collections.abc import Callable
from typing import Any, NamedTuple, TypeVar

import numpy as np

from ovis.common.messages import ObstacleFrame
from ovis.common.ros2.cdr import (
    COMPRESSED_IMAGE,
    MARKER_ARRAY,
    ODOMETRY,
    POSE_ARRAY,
    RosMessage,
    ros_message,
    ros_time,
    typestore,
)
from ovis.common.ros2.floor import NOT_MEASURED, RIGHT_HANDED, RosFloor, Terms

__all__ = ["obstacle_messages"]

#: Marker looks (RGBA): obstacles, robots, id texts; text height and arrow shaft (m).
_OBSTACLE_RGBA = (0.95, 0.55, 0.1, 0.8)
_ROBOT_RGBA = (0.1, 0.8, 0.3, 0.9)
_TEXT_RGBA = (1.0, 1.0, 1.0, 1.0)
_CLEAR_RGBA = (0.0, 0.0, 0.0, 0.0)
_TEXT_M = 0.05
_SHAFT_M = 0.02
_NO_BYTES = np.zeros(0, dtype=np.uint8)
_T = TypeVar("_T")


class _Robot(NamedTuple):
    """A robot as the messages need it: a marked robot's state, or the unmarked one."""

    id: int
    x_cm: float
    y_cm: float
    z_cm: float
    radius_cm: float
    heading_deg: float | None
    vx_cm_s: float
    vy_cm_s: float
    yaw_rate_deg_s: float | None
    velocity_measured: bool
    marked: bool


def _robots(frame: ObstacleFrame) -> list[_Robot]:
    if frame.robots:
        return [
            _Robot(r.id, r.x_cm, r.y_cm, r.z_cm, r.radius_cm, r.heading_deg, r.vx_cm_s,
                   r.vy_cm_s, r.yaw_rate_deg_s, r.velocity_measured, True)
            for r in frame.robots
        ]  # fmt: skip
    r = frame.robot
    if r is None:
        return []
    heading = r.heading_deg if r.heading_resolved else None
    return [
        _Robot(r.id, r.x_cm, r.y_cm, r.z_cm, r.radius_cm, heading, r.vx_cm_s, r.vy_cm_s,
               None, r.velocity_measured, False)
    ]  # fmt: skip


class _Shared:
    """The parts that never change, shared by every message of every thread (the
    serialiser only reads them)."""

    def __init__(self) -> None:
        T = self.T = typestore().types
        self.forever = T["builtin_interfaces/msg/Duration"](sec=0, nanosec=0)
        self.no_mesh = T["visualization_msgs/msg/MeshFile"](filename="", data=_NO_BYTES)
        color = T["std_msgs/msg/ColorRGBA"]
        self.obstacle, self.robot = color(*_OBSTACLE_RGBA), color(*_ROBOT_RGBA)
        self.text, self.clear = color(*_TEXT_RGBA), color(*_CLEAR_RGBA)
        #: covariance of what ovis does not measure (never written to)
        self.unmeasured = np.diag([NOT_MEASURED] * 6).ravel()
        M = self.Marker = T["visualization_msgs/msg/Marker"]
        self.ADD, self.DELETEALL = M.ADD, M.DELETEALL
        self.CYLINDER, self.ARROW, self.TEXT = M.CYLINDER, M.ARROW, M.TEXT_VIEW_FACING

    def vector(self) -> Any:
        return self.T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)

    def pose(self) -> Any:
        T = self.T
        return T["geometry_msgs/msg/Pose"](
            position=T["geometry_msgs/msg/Point"](x=0.0, y=0.0, z=0.0),
            orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
        )


@functools.cache
def _shared() -> _Shared:
    return _Shared()


class _Kept(threading.local):
    """One thread's message objects, kept between frames (pools grow to the largest
    frame seen)."""

    def __init__(self) -> None:
        s = _shared()
        T = s.T
        self.header = T["std_msgs/msg/Header"](
            stamp=T["builtin_interfaces/msg/Time"](sec=0, nanosec=0), frame_id=""
        )
        self.texture = T[COMPRESSED_IMAGE](header=self.header, format="", data=_NO_BYTES)
        self.pose_array = T[POSE_ARRAY](header=self.header, poses=[])
        self.marker_array = T[MARKER_ARRAY](markers=[])
        self.poses: list[Any] = []
        self.markers: list[Any] = []
        self.odometry: list[Any] = []

    def marker(self) -> Any:
        s = _shared()
        return s.Marker(
            header=self.header, ns="", id=0, type=0, action=0, pose=s.pose(), scale=s.vector(),
            color=s.clear, lifetime=s.forever, frame_locked=False, points=[], colors=[],
            texture_resource="", texture=self.texture, uv_coordinates=[], text="",
            mesh_resource="", mesh_file=s.no_mesh, mesh_use_embedded_materials=False,
        )  # fmt: skip

    def odom(self) -> Any:
        s = _shared()
        T = s.T
        return T[ODOMETRY](
            header=self.header,
            child_frame_id="",
            pose=T["geometry_msgs/msg/PoseWithCovariance"](
                pose=s.pose(), covariance=s.unmeasured.copy()
            ),
            twist=T["geometry_msgs/msg/TwistWithCovariance"](
                twist=T["geometry_msgs/msg/Twist"](linear=s.vector(), angular=s.vector()),
                covariance=s.unmeasured,
            ),
        )


_KEPT = _Kept()


def _taken(pool: list[_T], n: int, make: Callable[[], _T]) -> list[_T]:
    """The first ``n`` objects of ``pool``, made as needed."""
    while len(pool) < n:
        pool.append(make())
    return pool[:n]


def _place(pose: Any, x: float, y: float, z: float, yaw: float) -> None:
    p, q = pose.position, pose.orientation
    p.x, p.y, p.z = x, y, z
    q.z, q.w = math.sin(yaw / 2.0), math.cos(yaw / 2.0)


def obstacle_messages(
    frame: ObstacleFrame, frame_id: str, floor: RosFloor = RIGHT_HANDED, markers: bool = True
) -> list[RosMessage]:
    """The frame's PoseArray (``obstacles``), MarkerArray (``markers``; not with
    ``markers=False``, e.g. between two of a lower marker rate) and one Odometry per
    robot (``robots/robot_<id>/odom``: ROS 2 refuses a name token that starts with a
    digit), all stamped with its capture time, in the floor frame
    ``frame_id`` mapped by ``floor`` (see :mod:`ovis.common.ros2.convert`)."""
    kept = _KEPT
    header = kept.header
    header.stamp.sec, header.stamp.nanosec = ros_time(frame.stamp_ns)
    header.frame_id = frame_id
    stamp = frame.stamp_ns
    robots = _robots(frame)
    poses = _taken(kept.poses, len(frame.obstacles), _shared().pose)
    for o, pose in zip(frame.obstacles, poses, strict=True):
        _place(pose, *floor.position_m(o.x_cm, o.y_cm, o.z_cm), _yaw(floor, o.heading_deg))
    kept.pose_array.poses = poses
    out = [ros_message(POSE_ARRAY, kept.pose_array, "obstacles", stamp)]
    if markers:
        kept.marker_array.markers = _markers(kept, frame, robots, floor)
        out.append(ros_message(MARKER_ARRAY, kept.marker_array, "markers", stamp))
    planars = floor.planar_terms([(r.x_cm, r.y_cm, r.z_cm) for r in robots])
    odoms = _taken(kept.odometry, len(robots), kept.odom)
    for r, planar, odom in zip(robots, planars, odoms, strict=True):
        _odometry(odom, r, planar, frame_id, floor)
        out.append(ros_message(ODOMETRY, odom, f"robots/robot_{r.id}/odom", stamp))
    return out


def _yaw(floor: RosFloor, heading_deg: float | None) -> float:
    return 0.0 if heading_deg is None else floor.yaw_rad(heading_deg)


def _markers(kept: _Kept, frame: ObstacleFrame, robots: list[_Robot], floor: RosFloor) -> list[Any]:
    """A DELETEALL, then each obstacle's cylinder and id, each robot's arrow and id."""
    s = _shared()
    n = 1 + 2 * (len(frame.obstacles) + len(robots))
    out = _taken(kept.markers, n, kept.marker)
    _mark(out[0], "", 0, s.ARROW, s.DELETEALL, (0.0, 0.0, 0.0), 0.0, (0.0, 0.0, 0.0), s.clear)
    k = 1
    for o in frame.obstacles:
        x, y, z = floor.position_m(o.x_cm, o.y_cm, o.z_cm)
        d, h = 2.0 * o.radius_cm / 100.0, max(z, 0.01)
        _mark(out[k], "obstacles", o.id, s.CYLINDER, s.ADD, (x, y, z / 2.0), 0.0, (d, d, h),
              s.obstacle)  # fmt: skip
        _text(out[k + 1], "obstacle_ids", o.id, (x, y, z), str(o.id))
        k += 2
    for r in robots:
        x, y, z = floor.position_m(r.x_cm, r.y_cm, r.z_cm)
        length = max(2.0 * r.radius_cm / 100.0, _SHAFT_M)
        _mark(out[k], "robots", r.id, s.ARROW, s.ADD, (x, y, z), _yaw(floor, r.heading_deg),
              (length, _SHAFT_M, _SHAFT_M), s.robot)  # fmt: skip
        _text(out[k + 1], "robot_ids", r.id, (x, y, z), f"robot {r.id}")
        k += 2
    return out


def _mark(
    m: Any,
    ns: str,
    id_: int,
    kind: int,
    action: int,
    xyz: tuple[float, float, float],
    yaw: float,
    scale: tuple[float, float, float],
    color: Any,
    text: str = "",
) -> None:
    """Rewrites a kept Marker."""
    m.ns, m.id, m.type, m.action = ns, int(id_) & 0x7FFFFFFF, kind, action
    m.color, m.text = color, text
    _place(m.pose, *xyz, yaw)
    v = m.scale
    v.x, v.y, v.z = scale


def _text(m: Any, ns: str, id_: int, xyz: tuple[float, float, float], text: str) -> None:
    s = _shared()
    above = (xyz[0], xyz[1], xyz[2] + 2.0 * _TEXT_M)
    _mark(m, ns, id_, s.TEXT, s.ADD, above, 0.0, (_TEXT_M, _TEXT_M, _TEXT_M), s.text, text)


def _odometry(odom: Any, r: _Robot, planar: Terms | None, frame_id: str, floor: RosFloor) -> None:
    """Rewrites a kept Odometry with robot ``r``."""
    yaw = _yaw(floor, r.heading_deg)
    odom.child_frame_id = f"{frame_id}/robot_{r.id}"
    _place(odom.pose.pose, *floor.position_m(r.x_cm, r.y_cm, r.z_cm), yaw)
    cov = odom.pose.covariance
    cov[:] = _shared().unmeasured
    if planar is not None:
        cov[0], cov[1], cov[7] = planar
        cov[6] = cov[1]
    if r.heading_deg is not None and r.marked:
        cov[35] = floor.yaw_variance(r.id, planar)
    # the twist is in the robot's own frame (child_frame_id): x forward, y left
    vx, vy = r.vx_cm_s / 100.0, floor.y_sign * r.vy_cm_s / 100.0
    c, s = math.cos(yaw), math.sin(yaw)
    wz = 0.0 if r.yaw_rate_deg_s is None else floor.yaw_rad(r.yaw_rate_deg_s)
    if not (r.velocity_measured and r.heading_deg is not None):
        vx = vy = wz = 0.0
    twist = odom.twist.twist
    twist.linear.x, twist.linear.y = c * vx + s * vy, -s * vx + c * vy
    twist.angular.z = wz
