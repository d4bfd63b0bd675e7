"""ovis's stream of messages as a stream of ROS 2 messages: what ``ovis up --ros2``
publishes (:mod:`ovis.services.ros2`), what ``ovis record --ros2`` writes into its bag
and what the benchmark row ``ros2`` measures.

It follows the calibration: each one gives CameraInfo and ``/tf_static``, and the floor
mapping (:func:`~ovis.common.ros2.floor.ros_floor`, built once per calibration) for
the obstacle frames after it. An obstacle frame that comes before any calibration is
not converted (its floor frame's handedness is not known yet) and counted in
:attr:`RosStream.waiting`. Of ``[ros2]`` it takes the namespace, the floor's frame id,
the topics and, paced (live), the rates of the topics people watch: the MarkerArray
and the camera image (with its CameraInfo) go out ``markers_rate_hz`` and
``image_rate_hz`` times a second by the frames' capture stamps (:class:`Rate`), the
poses and odometry with every frame. Unpaced (a recording), every message goes.
"""

from __future__ import annotations

from collections.abc import Iterable

from ovis.common.calibration.file import Calibration
from ovis.common.config import Ros2Config
from ovis.common.messages import Frame, ObstacleFrame
from ovis.common.ros2.convert import (
    RosMessage,
    camera_info_message,
    camera_messages,
    image_message,
    obstacle_messages,
)
from ovis.common.ros2.floor import RosFloor, ros_floor
from ovis.common.ros2.topics import topic_kind
from ovis.common.ros2.wire import qualified_name

__all__ = ["Rate", "RosStream"]


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
    """Converts one arena's messages as they come: obstacle frames in one thread,
    camera frames in one (the same or another), calibrations in any."""

    def __init__(self, cfg: Ros2Config | None = None, *, paced: bool = True) -> None:
        cfg = cfg or Ros2Config()
        self.namespace = cfg.namespace
        self.frame_id = cfg.frame_id
        self.jpeg_quality = cfg.image_quality
        self.kinds = frozenset(cfg.topics)
        self.floor: RosFloor | None = None
        self.calib: Calibration | None = None
        self.waiting = 0  # obstacle frames not converted: no calibration yet

        def rate(hz: float, chosen: bool) -> Rate:  # unpaced: every one; not chosen: none
            return Rate((hz if paced else None) if chosen else 0.0)

        self.markers = rate(cfg.markers_rate_hz, "markers" in self.kinds)
        self.images = rate(cfg.image_rate_hz, bool(self.kinds & {"image", "camera_info"}))

    def topic(self, message: RosMessage) -> str:
        """The message's full ROS 2 topic name (``/ovis/obstacles``, ``/tf_static``)."""
        return qualified_name(self.namespace, message.topic)

    def selected(self, messages: Iterable[RosMessage]) -> list[RosMessage]:
        """Those of ``messages`` on the ``[ros2] topics``."""
        return [m for m in messages if topic_kind(m.topic) in self.kinds]

    def calibration(self, calib: Calibration, stamp_ns: int) -> list[RosMessage]:
        """CameraInfo and ``/tf_static`` of a new calibration (stamped ``stamp_ns``);
        the obstacle frames after it are mapped with its floor."""
        self.floor = ros_floor(calib)
        self.calib = calib
        return self.selected(camera_messages(calib, self.frame_id, stamp_ns))

    def obstacles(self, frame: ObstacleFrame) -> list[RosMessage]:
        """The frame's obstacles, odometry and (when due) markers; none before a
        calibration."""
        floor = self.floor
        if floor is None:
            self.waiting += 1
            return []
        due = self.markers.due(frame.stamp_ns)
        return self.selected(obstacle_messages(frame, self.frame_id, floor, markers=due))

    def image_due(self, stamp_ns: int) -> bool:
        """Whether the camera frame captured at ``stamp_ns`` goes out (counted if so):
        asked before the frame's image is even decoded."""
        return self.images.due(stamp_ns)

    def image(self, frame: Frame) -> list[RosMessage]:
        """The frame as a compressed image, with the CameraInfo of the calibration in use
        stamped as the image (as a ROS 2 camera driver publishes them; none before a
        calibration)."""
        out = [image_message(frame, self.jpeg_quality)] if "image" in self.kinds else []
        calib = self.calib
        if calib is not None:
            out += self.selected([camera_info_message(calib, frame.stamp_ns)])
        return out

    def images_due(self, frame: Frame) -> list[RosMessage]:
        """:meth:`image` when the frame is due, else nothing."""
        return self.image(frame) if self.image_due(frame.stamp_ns) else []
