"""Which of the ``[ros2] topics`` a ROS 2 message belongs to, and the QoS each is
offered with, by ovis's ROS 2 node and in its bags alike: the camera's model and the
floor → camera transform change only with the calibration, so they are kept for late
subscribers (transient local, depth 1, as ``/tf_static`` is everywhere in ROS 2); the
rest is a stream (volatile, depth 10). Both reliable."""

from __future__ import annotations

from ovis.common.ros2.wire import TRANSIENT_LOCAL, QoS

__all__ = ["KEPT", "STREAM", "qos_of", "topic_kind"]

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
    absolute) comes under: ``robots/robot_<id>/odom`` is ``odom``; an unknown topic is
    its own name (never selected)."""
    parts = topic.split("/")
    if len(parts) == 3 and parts[0] == "robots" and parts[2] == "odom":
        return "odom"
    return _KINDS.get(topic, topic)


def qos_of(topic: str) -> QoS:
    """The QoS of a message's topic (relative to the namespace, or absolute)."""
    return KEPT if topic_kind(topic) in ("camera_info", "tf_static") else STREAM
