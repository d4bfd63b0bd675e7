"""ovis messages as standard ROS 2 messages, CDR-serialised: what a ROS 2 node reads.

Types, their CDR (little-endian, with the 4-byte encapsulation header rmw_zenoh sends),
their ``RIHS01`` type hashes and their ``ros2msg`` definitions all come from
`rosbags <https://gitlab.com/ternaris/rosbags>`_' typestore of **ROS 2 Jazzy**
(``Stores.ROS2_JAZZY``; these types and hashes are the same in Kilted). No ROS 2
installation is needed.

Topics are relative to the namespace (``obstacles``) or absolute (``/tf_static``):

* ``obstacles`` — ``geometry_msgs/msg/PoseArray``: each obstacle's centre on its top
  plane (yaw: its axis, when it has one);
* ``markers`` — ``visualization_msgs/msg/MarkerArray``: a DELETEALL, then obstacles as
  cylinders of their radius and height, robots as arrows along their heading, ids as
  text above them;
* ``robots/<id>/odom`` — ``nav_msgs/msg/Odometry`` per robot (marked robots; without
  them the unmarked robot): pose and heading in the floor frame, twist in the robot's
  own frame (``child_frame_id``), covariances from :mod:`ovis.common.ros2.floor`;
* ``camera/camera_info`` — ``sensor_msgs/msg/CameraInfo``: ``ovis export --ros``'s
  numbers (:func:`ovis.common.camera.export.ros_camera_info`);
* ``/tf_static`` — ``tf2_msgs/msg/TFMessage``: floor → camera optical frame;
* ``camera/image/compressed`` — ``sensor_msgs/msg/CompressedImage``, JPEG.

Every header stamp is the frame's capture time. Positions and headings go through
:class:`~ovis.common.ros2.floor.RosFloor` (REP 103: metres, radians, right-handed; see
there how ovis's floor maps to it). Pass ``floor=ros_floor(calibration)``: without it
the floor is taken as right-handed (a pinhole calibration's) with no accuracy known.
"""

from __future__ import annotations

import functools
import math
from typing import Any, NamedTuple

import cv2
import msgspec
import numpy as np
from rosbags.typesys import Stores, get_typestore
from scipy.spatial.transform import Rotation

from ovis.common.calibration.file import Calibration
from ovis.common.camera.export import as_pinhole, ros_camera_info
from ovis.common.messages import Frame, ObstacleFrame
from ovis.common.ros2.floor import NOT_MEASURED, RIGHT_HANDED, RosFloor, ros_floor

__all__ = [
    "CAMERA_FRAME",
    "STORE",
    "RosMessage",
    "camera_messages",
    "image_message",
    "message_definition",
    "obstacle_messages",
    "type_hash",
    "typestore",
]

#: The rosbags typestore the types come from.
STORE = Stores.ROS2_JAZZY
#: The camera's optical frame (x right, y down the image, z forward), CameraInfo's and
#: the image's ``frame_id`` and the child of ``/tf_static``.
CAMERA_FRAME = "ovis_camera_optical"

POSE_ARRAY = "geometry_msgs/msg/PoseArray"
MARKER_ARRAY = "visualization_msgs/msg/MarkerArray"
ODOMETRY = "nav_msgs/msg/Odometry"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"

#: Marker looks (RGBA): obstacles, robots, id texts; text height and arrow shaft (m).
_OBSTACLE_RGBA = (0.95, 0.55, 0.1, 0.8)
_ROBOT_RGBA = (0.1, 0.8, 0.3, 0.9)
_TEXT_RGBA = (1.0, 1.0, 1.0, 1.0)
_TEXT_M = 0.05
_SHAFT_M = 0.02
#: The last second builtin_interfaces/Time holds (int32).
_MAX_SEC = 2**31 - 1


class RosMessage(msgspec.Struct, frozen=True):
    """One ROS 2 message ready to publish or record."""

    topic: str  # relative to the namespace ("obstacles", "robots/3/odom"); absolute with "/"
    type: str  # ROS 2 type name, e.g. "geometry_msgs/msg/PoseArray"
    cdr: bytes  # CDR little-endian, with the 4-byte encapsulation header
    stamp_ns: int  # the source time: the frame's capture time


@functools.cache
def typestore() -> Any:
    """rosbags' typestore of :data:`STORE` (built once)."""
    return get_typestore(STORE)


def type_hash(type_name: str) -> str:
    """The type's ``RIHS01_<64 hex>`` hash (REP 2016), as rmw_zenoh keys carry it."""
    return str(typestore().hash_rihs01(type_name))


@functools.cache
def message_definition(type_name: str) -> str:
    """The type's ``ros2msg`` definition with its dependencies, as ``ros2 bag`` writes
    it in an MCAP schema."""
    return str(typestore().generate_msgdef(type_name, ros_version=2)[0])


def _message(type_name: str, message: Any, topic: str, stamp_ns: int) -> RosMessage:
    cdr = bytes(typestore().serialize_cdr(message, type_name, little_endian=True))
    return RosMessage(topic, type_name, cdr, stamp_ns)


class _Builders:
    """Constructors of the nested types (the typestore's classes)."""

    def __init__(self) -> None:
        self.T = typestore().types

    def header(self, stamp_ns: int, frame_id: str) -> Any:
        sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
        if sec > _MAX_SEC:
            raise ValueError(
                f"stamp {stamp_ns} ns is after 2038-01-19: ROS 2 time holds int32 seconds"
            )
        time = self.T["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec)
        return self.T["std_msgs/msg/Header"](stamp=time, frame_id=frame_id)

    def pose(self, xyz: tuple[float, float, float], yaw: float) -> Any:
        point = self.T["geometry_msgs/msg/Point"](x=xyz[0], y=xyz[1], z=xyz[2])
        q = self.T["geometry_msgs/msg/Quaternion"](
            x=0.0, y=0.0, z=math.sin(yaw / 2.0), w=math.cos(yaw / 2.0)
        )
        return self.T["geometry_msgs/msg/Pose"](position=point, orientation=q)

    def vector(self, x: float, y: float, z: float) -> Any:
        return self.T["geometry_msgs/msg/Vector3"](x=x, y=y, z=z)


@functools.cache
def _builders() -> _Builders:
    return _Builders()


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


def obstacle_messages(
    frame: ObstacleFrame, frame_id: str, floor: RosFloor = RIGHT_HANDED
) -> list[RosMessage]:
    """The frame's PoseArray (``obstacles``), MarkerArray (``markers``) and one Odometry
    per robot (``robots/<id>/odom``), all stamped with its capture time, in the floor
    frame ``frame_id`` mapped by ``floor`` (see the module docstring)."""
    b = _builders()
    header = b.header(frame.stamp_ns, frame_id)
    robots = _robots(frame)
    poses = [
        b.pose(floor.position_m(o.x_cm, o.y_cm, o.z_cm), _yaw(floor, o.heading_deg))
        for o in frame.obstacles
    ]
    out = [
        _message(
            POSE_ARRAY,
            b.T[POSE_ARRAY](header=header, poses=poses),
            "obstacles",
            frame.stamp_ns,
        ),
        _message(
            MARKER_ARRAY,
            b.T[MARKER_ARRAY](markers=_markers(frame, robots, header, floor)),
            "markers",
            frame.stamp_ns,
        ),
    ]
    out += [_odometry(r, header, frame_id, floor, frame.stamp_ns) for r in robots]
    return out


def _yaw(floor: RosFloor, heading_deg: float | None) -> float:
    return 0.0 if heading_deg is None else floor.yaw_rad(heading_deg)


def _markers(frame: ObstacleFrame, robots: list[_Robot], header: Any, floor: RosFloor) -> list[Any]:
    b = _builders()
    marker = b.T["visualization_msgs/msg/Marker"]
    clear = _marker(header, "", 0, 0, marker.DELETEALL, b.pose((0.0, 0.0, 0.0), 0.0),
                    (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 0.0))  # fmt: skip
    out = [clear]
    for o in frame.obstacles:
        x, y, z = floor.position_m(o.x_cm, o.y_cm, o.z_cm)
        d, h = 2.0 * o.radius_cm / 100.0, max(z, 0.01)
        centre = b.pose((x, y, z / 2.0), 0.0)
        out.append(_marker(header, "obstacles", o.id, marker.CYLINDER, marker.ADD, centre,
                           (d, d, h), _OBSTACLE_RGBA))  # fmt: skip
        out.append(_text(header, "obstacle_ids", o.id, (x, y, z), str(o.id)))
    for r in robots:
        x, y, z = floor.position_m(r.x_cm, r.y_cm, r.z_cm)
        length = max(2.0 * r.radius_cm / 100.0, _SHAFT_M)
        pose = b.pose((x, y, z), _yaw(floor, r.heading_deg))
        out.append(_marker(header, "robots", r.id, marker.ARROW, marker.ADD, pose,
                           (length, _SHAFT_M, _SHAFT_M), _ROBOT_RGBA))  # fmt: skip
        out.append(_text(header, "robot_ids", r.id, (x, y, z), f"robot {r.id}"))
    return out


def _text(header: Any, ns: str, id_: int, xyz: tuple[float, float, float], text: str) -> Any:
    b = _builders()
    marker = b.T["visualization_msgs/msg/Marker"]
    above = b.pose((xyz[0], xyz[1], xyz[2] + 2.0 * _TEXT_M), 0.0)
    return _marker(header, ns, id_, marker.TEXT_VIEW_FACING, marker.ADD, above,
                   (_TEXT_M, _TEXT_M, _TEXT_M), _TEXT_RGBA, text)  # fmt: skip


def _marker(
    header: Any,
    ns: str,
    id_: int,
    kind: int,
    action: int,
    pose: Any,
    scale: tuple[float, float, float],
    rgba: tuple[float, float, float, float],
    text: str = "",
) -> Any:
    b = _builders()
    T = b.T
    return T["visualization_msgs/msg/Marker"](
        header=header, ns=ns, id=int(id_) & 0x7FFFFFFF, type=kind, action=action, pose=pose,
        scale=b.vector(*scale), color=T["std_msgs/msg/ColorRGBA"](*rgba),
        lifetime=T["builtin_interfaces/msg/Duration"](sec=0, nanosec=0), frame_locked=False,
        points=[], colors=[], texture_resource="", texture=_EMPTY_IMAGE(header),
        uv_coordinates=[], text=text, mesh_resource="",
        mesh_file=T["visualization_msgs/msg/MeshFile"](filename="", data=_NO_BYTES),
        mesh_use_embedded_materials=False,
    )  # fmt: skip


_NO_BYTES = np.zeros(0, dtype=np.uint8)


def _EMPTY_IMAGE(header: Any) -> Any:  # noqa: N802  (reads as the constant it stands for)
    return _builders().T[COMPRESSED_IMAGE](header=header, format="", data=_NO_BYTES)


def _odometry(r: _Robot, header: Any, frame_id: str, floor: RosFloor, stamp_ns: int) -> RosMessage:
    b = _builders()
    T = b.T
    xyz = floor.position_m(r.x_cm, r.y_cm, r.z_cm)
    yaw = _yaw(floor, r.heading_deg)
    planar = floor.planar_covariance(r.x_cm, r.y_cm, r.z_cm)
    pose_cov = np.diag([NOT_MEASURED] * 6)
    if planar is not None:
        pose_cov[:2, :2] = planar
    if r.heading_deg is not None and r.marked:
        pose_cov[5, 5] = floor.yaw_variance(r.id, planar)
    # the twist is in the robot's own frame (child_frame_id): x forward, y left
    vx, vy = r.vx_cm_s / 100.0, floor.y_sign * r.vy_cm_s / 100.0
    c, s = math.cos(yaw), math.sin(yaw)
    wz = 0.0 if r.yaw_rate_deg_s is None else floor.yaw_rad(r.yaw_rate_deg_s)
    measured = r.velocity_measured and r.heading_deg is not None
    if not measured:
        vx = vy = wz = 0.0
    twist = T["geometry_msgs/msg/Twist"](
        linear=b.vector(c * vx + s * vy, -s * vx + c * vy, 0.0), angular=b.vector(0.0, 0.0, wz)
    )
    message = T[ODOMETRY](
        header=header,
        child_frame_id=f"{frame_id}/robot_{r.id}",
        pose=T["geometry_msgs/msg/PoseWithCovariance"](
            pose=b.pose(xyz, yaw), covariance=pose_cov.ravel()
        ),
        twist=T["geometry_msgs/msg/TwistWithCovariance"](
            twist=twist, covariance=np.diag([NOT_MEASURED] * 6).ravel()
        ),
    )
    return _message(ODOMETRY, message, f"robots/{r.id}/odom", stamp_ns)


def camera_messages(
    calib: Calibration, frame_id: str, stamp_ns: int, camera_frame: str = CAMERA_FRAME
) -> list[RosMessage]:
    """CameraInfo (``camera/camera_info``, ``ovis export --ros``'s numbers, in the
    mirrored camera frame for a mirrored floor: see :mod:`ovis.common.ros2.floor`) and
    ``/tf_static`` (floor ``frame_id`` → ``camera_frame``: where the camera is and how
    it is turned, from the calibration's pose)."""
    b = _builders()
    T = b.T
    cam = as_pinhole(calib.camera).camera
    floor = ros_floor(calib)
    info = ros_camera_info(cam)
    flip = np.diag([1.0, floor.y_sign, 1.0])  # the floor's and the camera's y flip
    # the camera's y flips: K's and P's y column (fy) and p1 (it multiplies y) change sign
    k = np.array(info["camera_matrix"]["data"]).reshape(3, 3) @ flip
    d = np.array(info["distortion_coefficients"]["data"], dtype=np.float64)
    d[2] *= floor.y_sign
    p = np.array(info["projection_matrix"]["data"]).reshape(3, 4) @ np.diag(
        [1.0, floor.y_sign, 1.0, 1.0]
    )
    camera_header = b.header(stamp_ns, camera_frame)
    roi = T["sensor_msgs/msg/RegionOfInterest"](
        x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
    )
    camera_info = T[CAMERA_INFO](
        header=camera_header, height=info["image_height"], width=info["image_width"],
        distortion_model=info["distortion_model"], d=d, k=k.ravel(),
        r=np.array(info["rectification_matrix"]["data"], dtype=np.float64), p=p.ravel(),
        binning_x=0, binning_y=0, roi=roi,
    )  # fmt: skip
    # world (cm, ovis) → camera: c = R·P + t; in ROS (m): c' = F·R·F·P' + F·t/100
    R = flip @ cv2.Rodrigues(np.array(cam.rvec, dtype=np.float64))[0] @ flip
    t = flip @ np.array(cam.tvec_cm, dtype=np.float64) / 100.0
    centre = -R.T @ t
    q = Rotation.from_matrix(R.T).as_quat()  # x, y, z, w: the camera's axes in the floor
    transform = T["geometry_msgs/msg/TransformStamped"](
        header=b.header(stamp_ns, frame_id),
        child_frame_id=camera_frame,
        transform=T["geometry_msgs/msg/Transform"](
            translation=b.vector(*(float(v) for v in centre)),
            rotation=T["geometry_msgs/msg/Quaternion"](*(float(v) for v in q)),
        ),
    )
    return [
        _message(CAMERA_INFO, camera_info, "camera/camera_info", stamp_ns),
        _message(TF_MESSAGE, T[TF_MESSAGE](transforms=[transform]), "/tf_static", stamp_ns),
    ]


def image_message(frame: Frame, quality: int = 80, camera_frame: str = CAMERA_FRAME) -> RosMessage:
    """The frame as a JPEG ``sensor_msgs/msg/CompressedImage``
    (``camera/image/compressed``, image_transport's ``format``)."""
    ok, jpeg = cv2.imencode(".jpg", frame.image(), [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise ValueError(f"frame {frame.seq} could not be encoded as JPEG")
    encoding = "mono8" if frame.channels == 1 else "bgr8"
    message = _builders().T[COMPRESSED_IMAGE](
        header=_builders().header(frame.stamp_ns, camera_frame),
        format=f"{encoding}; jpeg compressed {encoding}",
        data=jpeg.reshape(-1),
    )
    return _message(COMPRESSED_IMAGE, message, "camera/image/compressed", frame.stamp_ns)
