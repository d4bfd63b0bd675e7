"""ROS 2 messages in CDR: the kept rosbags typestore of ROS 2 Jazzy (types, their
``RIHS01`` hashes and ``ros2msg`` definitions; these types and hashes are the same in
Kilted) and :class:`RosMessage`, one serialised message with its topic and source time.
No ROS 2 installation is needed."""

from __future__ import annotations

import functools
from typing import Any

import msgspec
from rosbags.typesys import Stores, get_typestore

__all__ = [
    "COMPRESSED_IMAGE",
    "MARKER_ARRAY",
    "ODOMETRY",
    "POSE_ARRAY",
    "STORE",
    "RosMessage",
    "message_definition",
    "ros_message",
    "ros_time",
    "type_hash",
    "typestore",
]

#: The rosbags typestore the types come from.
STORE = Stores.ROS2_JAZZY

POSE_ARRAY = "geometry_msgs/msg/PoseArray"
MARKER_ARRAY = "visualization_msgs/msg/MarkerArray"
ODOMETRY = "nav_msgs/msg/Odometry"
COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"

#: The last second builtin_interfaces/Time holds (int32).
_MAX_SEC = 2**31 - 1


class RosMessage(msgspec.Struct, frozen=True):
    """One ROS 2 message ready to publish or record."""

    topic: str  # relative to the namespace ("obstacles", "robots/robot_3/odom"); absolute with "/"
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


def ros_message(type_name: str, message: Any, topic: str, stamp_ns: int) -> RosMessage:
    """``message`` (an object of the typestore's ``type_name``) serialised by rosbags."""
    cdr = bytes(typestore().serialize_cdr(message, type_name, little_endian=True))
    return RosMessage(topic, type_name, cdr, stamp_ns)


def ros_time(stamp_ns: int) -> tuple[int, int]:
    """A stamp (ns since the epoch) as builtin_interfaces/Time's ``(sec, nanosec)``;
    a stamp it cannot hold is refused with the reason."""
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    if sec > _MAX_SEC:
        raise ValueError(f"stamp {stamp_ns} ns is after 2038-01-19: ROS 2 time holds int32 seconds")
    return sec, nanosec
