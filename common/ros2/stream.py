"""ovis's stream of messages as a stream of ROS 2 messages: what ``ovis record --ros2``
writes beside ovis's own channels (and what any ROS 2 output needs).

It follows the calibration: each one gives CameraInfo and ``/tf_static``, and the floor
mapping (:func:`~ovis.common.ros2.floor.ros_floor`) for the obstacle frames after it.
An obstacle frame that comes before any calibration is not converted (its floor
frame's handedness is not known yet) and counted in :attr:`RosStream.waiting`.
"""

from __future__ import annotations

from ovis.common.calibration.file import Calibration
from ovis.common.messages import Frame, ObstacleFrame
from ovis.common.ros2.convert import (
    RosMessage,
    camera_messages,
    image_message,
    obstacle_messages,
)
from ovis.common.ros2.floor import RosFloor, ros_floor

__all__ = ["DEFAULT_FRAME_ID", "DEFAULT_NAMESPACE", "RosStream"]

DEFAULT_NAMESPACE = "/ovis"
DEFAULT_FRAME_ID = "ovis_floor"


class RosStream:
    """Converts one arena's messages as they come (one thread)."""

    def __init__(
        self,
        namespace: str = DEFAULT_NAMESPACE,
        frame_id: str = DEFAULT_FRAME_ID,
        jpeg_quality: int = 80,
    ) -> None:
        self.namespace = "/" + namespace.strip("/") if namespace.strip("/") else ""
        self.frame_id = frame_id
        self.jpeg_quality = jpeg_quality
        self.floor: RosFloor | None = None
        self.waiting = 0  # obstacle frames not converted: no calibration yet

    def topic(self, message: RosMessage) -> str:
        """The message's full ROS 2 topic name (``/ovis/obstacles``, ``/tf_static``)."""
        if message.topic.startswith("/"):
            return message.topic
        return f"{self.namespace}/{message.topic}"

    def calibration(self, calib: Calibration, stamp_ns: int) -> list[RosMessage]:
        """CameraInfo and ``/tf_static`` of a new calibration (stamped ``stamp_ns``)."""
        self.floor = ros_floor(calib)
        return camera_messages(calib, self.frame_id, stamp_ns)

    def obstacles(self, frame: ObstacleFrame) -> list[RosMessage]:
        """The frame's obstacles, markers and odometry; none before a calibration."""
        if self.floor is None:
            self.waiting += 1
            return []
        return obstacle_messages(frame, self.frame_id, self.floor)

    def image(self, frame: Frame) -> RosMessage:
        """The frame as a compressed image."""
        return image_message(frame, self.jpeg_quality)
