"""Which of the ``[ros2] topics`` a ROS 2 message belongs to, and the QoS each is
published with: the camera's model and the floor → camera transform change only with
the calibration, so they are kept for late subscribers (transient local, depth 1, as
``/tf_static`` is everywhere in ROS 2); the rest is a stream (volatile, depth 10)."""

from __future__ import annotations

from ovis.common.ros2.wire import TRANSIENT_LOCAL, QoS

__all__ = ["KEPT", "STREAM", "ImagePacer", "qos_of", "ros_topic", "topic_kind"]

#: QoS of what is kept for late subscribers, and of the streams.
KEPT = QoS(durability=TRANSIENT_LOCAL, depth=1)
STREAM = QoS(depth=10)

_KINDS = {
    "obstacles": "obstacles",
    "markers": "markers",
    "camera/camera_info": "camera_info",
    "camera/image/compressed": "image",
    "/tf_static": "tf_static",
}


def topic_kind(topic: str) -> str:
    """The ``[ros2] topics`` entry a message's topic (relative to the namespace, or
    absolute) comes under: ``robots/<robot>/odom`` is ``odom``; an unknown topic is its
    own name (never selected)."""
    parts = topic.split("/")
    if len(parts) == 3 and parts[0] == "robots" and parts[2] == "odom":
        return "odom"
    return _KINDS.get(topic, topic)


def ros_topic(topic: str) -> str:
    """A topic as ROS 2 accepts it: no name token may start with a digit (rmw's
    ``RMW_TOPIC_INVALID_NAME_TOKEN_STARTS_WITH_NUMBER``), so robot 3's
    ``robots/3/odom`` is published as ``robots/robot_3/odom``."""
    parts = topic.split("/")
    if topic_kind(topic) == "odom" and parts[1][:1].isdigit():
        return f"robots/robot_{parts[1]}/odom"
    return topic


def qos_of(kind: str) -> QoS:
    return KEPT if kind in ("camera_info", "tf_static") else STREAM


class ImagePacer:
    """Lets a camera image through at most ``rate_hz`` times a second (0: never), so
    that the frames in between are not even copied."""

    def __init__(self, rate_hz: float) -> None:
        self.period_ns = round(1e9 / rate_hz) if rate_hz > 0 else None
        self._next_ns = 0

    def due(self, now_ns: int) -> bool:
        """Whether an image taken now goes out (and, if so, the next one a period later)."""
        if self.period_ns is None or now_ns < self._next_ns:
            return False
        self._next_ns = now_ns + self.period_ns
        return True
