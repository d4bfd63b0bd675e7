"""ovis's stream of messages as a stream of ROS 2 messages: what ``ovis record --ros2``
writes into its bag (and what any ROS 2 output needs).

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

__all__ = [
    "DEFAULT_FRAME_ID",
    "DEFAULT_IMAGE_HZ",
    "DEFAULT_MARKERS_HZ",
    "DEFAULT_NAMESPACE",
    "Rate",
    "RosStream",
]

DEFAULT_NAMESPACE = "/ovis"
DEFAULT_FRAME_ID = "ovis_floor"
#: rates (per second) of the visual-only topics where a live output paces them
DEFAULT_MARKERS_HZ = 2.0
DEFAULT_IMAGE_HZ = 1.0


class Rate:
    """Lets ``hz`` stamps a second through (on average, whatever the frame rate), the
    first one at once; None lets every stamp through, 0 none. A stamp that goes back
    in time (a new stream) starts it afresh."""

    def __init__(self, hz: float | None) -> None:
        if hz is not None and hz < 0.0:
            raise ValueError(f"a rate of {hz} per second: give 0 or more")
        self.hz = hz
        self._next_ns: int | None = None

    def due(self, stamp_ns: int) -> bool:
        """Whether the message of this stamp goes out (and, if it does, counts it)."""
        if self.hz is None:
            return True
        if self.hz == 0.0:
            return False
        period = round(1e9 / self.hz)
        nxt = self._next_ns
        if nxt is not None and nxt - period <= stamp_ns < nxt:
            return False
        # on time: the next one a period after this one was due; late or a new stream:
        # a period after this one
        on_time = nxt is not None and nxt <= stamp_ns < nxt + period
        self._next_ns = (nxt if on_time else stamp_ns) + period
        return True


class RosStream:
    """Converts one arena's messages as they come (one thread)."""

    def __init__(
        self,
        namespace: str = DEFAULT_NAMESPACE,
        frame_id: str = DEFAULT_FRAME_ID,
        jpeg_quality: int = 80,
        markers_hz: float | None = None,
        image_hz: float | None = None,
    ) -> None:
        self.namespace = "/" + namespace.strip("/") if namespace.strip("/") else ""
        self.frame_id = frame_id
        self.jpeg_quality = jpeg_quality
        self.floor: RosFloor | None = None
        self.waiting = 0  # obstacle frames not converted: no calibration yet
        self.markers = Rate(markers_hz)
        self.images = Rate(image_hz)

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
        """The frame's obstacles, odometry and (when due) markers; none before a
        calibration."""
        if self.floor is None:
            self.waiting += 1
            return []
        due = self.markers.due(frame.stamp_ns)
        return obstacle_messages(frame, self.frame_id, self.floor, markers=due)

    def image(self, frame: Frame) -> RosMessage:
        """The frame as a compressed image."""
        return image_message(frame, self.jpeg_quality)

    def images_due(self, frame: Frame) -> list[RosMessage]:
        """The frame as a compressed image when one is due, else nothing."""
        return [self.image(frame)] if self.images.due(frame.stamp_ns) else []
