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
* ``robots/robot_<id>/odom`` — ``nav_msgs/msg/Odometry`` per robot (marked robots; without
  them the unmarked robot): pose and heading in the floor frame, twist in the robot's
  own frame (``child_frame_id``), covariances from :mod:`ovis.common.ros2.floor`;
* ``camera/camera_info`` — ``sensor_msgs/msg/CameraInfo``: ``ovis export --ros``'s
  numbers (:func:`ovis.common.camera.export.ros_camera_info`);
* ``/tf_static`` — ``tf2_msgs/msg/TFMessage``: floor → camera optical frame;
* ``camera/image/compressed`` — ``sensor_msgs/msg/CompressedImage``, JPEG.

Every header stamp is the frame's capture time. The obstacle frames' messages are
built in :mod:`ovis.common.ros2.obstacles`, the CDR and types in
:mod:`ovis.common.ros2.cdr`; this module gives them all. Positions and headings go through
:class:`~ovis.common.ros2.floor.RosFloor` (REP 103: metres, radians, right-handed; see
there how ovis's floor maps to it). Pass ``floor=ros_floor(calibration)``: without it
the floor is taken as right-handed (a pinhole calibration's) with no accuracy known.
"""

from __future__ import annotations

import functools
from typing import Any, NamedTuple

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from ovis.common.calibration.file import Calibration
from ovis.common.camera.export import ros_camera_info
from ovis.common.messages import Frame
from ovis.common.ros2.cdr import (
    COMPRESSED_IMAGE,
    STORE,
    RosMessage,
    message_definition,
    ros_message,
    ros_time,
    type_hash,
    typestore,
)
from ovis.common.ros2.floor import last_kept, pinhole_of, ros_floor
from ovis.common.ros2.obstacles import obstacle_messages

__all__ = [
    "CAMERA_FRAME",
    "STORE",
    "RosMessage",
    "camera_info_message",
    "camera_messages",
    "image_message",
    "message_definition",
    "obstacle_messages",
    "type_hash",
    "typestore",
]

#: The camera's optical frame (x right, y down the image, z forward), CameraInfo's and
#: the image's ``frame_id`` and the child of ``/tf_static``.
CAMERA_FRAME = "ovis_camera_optical"

CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"


class _Builders:
    """Constructors of the nested types (the typestore's classes)."""

    def __init__(self) -> None:
        self.T = typestore().types

    def header(self, stamp_ns: int, frame_id: str) -> Any:
        sec, nanosec = ros_time(stamp_ns)
        time = self.T["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec)
        return self.T["std_msgs/msg/Header"](stamp=time, frame_id=frame_id)

    def vector(self, x: float, y: float, z: float) -> Any:
        return self.T["geometry_msgs/msg/Vector3"](x=x, y=y, z=z)


@functools.cache
def _builders() -> _Builders:
    return _Builders()


class _CameraParts(NamedTuple):
    """What a calibration's CameraInfo and ``/tf_static`` hold, stamp and frame names
    aside: worked out once per calibration (:func:`_camera_parts`)."""

    height: int
    width: int
    distortion_model: str
    d: NDArray[np.float64]
    k: NDArray[np.float64]
    r: NDArray[np.float64]
    p: NDArray[np.float64]
    centre: tuple[float, float, float]
    rotation: tuple[float, float, float, float]


@last_kept
def _camera_parts(calib: Calibration) -> _CameraParts:
    cam = pinhole_of(calib)
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
    # world (cm, ovis) → camera: c = R·P + t; in ROS (m): c' = F·R·F·P' + F·t/100
    R = flip @ cv2.Rodrigues(np.array(cam.rvec, dtype=np.float64))[0] @ flip
    t = flip @ np.array(cam.tvec_cm, dtype=np.float64) / 100.0
    centre = -R.T @ t
    q = Rotation.from_matrix(R.T).as_quat()  # x, y, z, w: the camera's axes in the floor
    return _CameraParts(
        info["image_height"], info["image_width"], info["distortion_model"], d, k.ravel(),
        np.array(info["rectification_matrix"]["data"], dtype=np.float64), p.ravel(),
        (float(centre[0]), float(centre[1]), float(centre[2])),
        (float(q[0]), float(q[1]), float(q[2]), float(q[3])),
    )  # fmt: skip


def camera_info_message(
    calib: Calibration, stamp_ns: int, camera_frame: str = CAMERA_FRAME
) -> RosMessage:
    """CameraInfo (``camera/camera_info``): ``ovis export --ros``'s numbers, in the
    mirrored camera frame for a mirrored floor (see :mod:`ovis.common.ros2.floor`)."""
    b = _builders()
    T = b.T
    c = _camera_parts(calib)
    roi = T["sensor_msgs/msg/RegionOfInterest"](
        x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
    )
    camera_info = T[CAMERA_INFO](
        header=b.header(stamp_ns, camera_frame), height=c.height, width=c.width,
        distortion_model=c.distortion_model, d=c.d, k=c.k, r=c.r, p=c.p,
        binning_x=0, binning_y=0, roi=roi,
    )  # fmt: skip
    return ros_message(CAMERA_INFO, camera_info, "camera/camera_info", stamp_ns)


def camera_messages(
    calib: Calibration, frame_id: str, stamp_ns: int, camera_frame: str = CAMERA_FRAME
) -> list[RosMessage]:
    """CameraInfo (:func:`camera_info_message`) and ``/tf_static`` (floor ``frame_id``
    → ``camera_frame``: where the camera is and how it is turned, from the
    calibration's pose)."""
    b = _builders()
    T = b.T
    c = _camera_parts(calib)
    transform = T["geometry_msgs/msg/TransformStamped"](
        header=b.header(stamp_ns, frame_id),
        child_frame_id=camera_frame,
        transform=T["geometry_msgs/msg/Transform"](
            translation=b.vector(*c.centre),
            rotation=T["geometry_msgs/msg/Quaternion"](*c.rotation),
        ),
    )
    return [
        camera_info_message(calib, stamp_ns, camera_frame),
        ros_message(TF_MESSAGE, T[TF_MESSAGE](transforms=[transform]), "/tf_static", stamp_ns),
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
    return ros_message(COMPRESSED_IMAGE, message, "camera/image/compressed", frame.stamp_ns)
