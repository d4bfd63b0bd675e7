"""``geometry_msgs/msg/TwistStamped`` in CDR written and read by the format's rules (not
ovis's nor rosbags' code), for tests that check what goes over ROS 2's ``cmd_vel``: a
4-byte encapsulation header (little-endian CDR: 00 01 00 00), then the stamp (int32 s,
uint32 ns), the frame_id (uint32 length with its NUL, the bytes), padding to 8, six
float64 (linear x y z, angular x y z)."""

from __future__ import annotations

import struct


def pack_twist_stamped(sec: int, nanosec: int, frame_id: str, six: tuple[float, ...]) -> bytes:
    name = frame_id.encode() + b"\0"
    body = struct.pack("<iII", sec, nanosec, len(name)) + name
    body += b"\0" * (-len(body) % 8)
    return b"\x00\x01\x00\x00" + body + struct.pack("<6d", *six)


def read_twist_stamped(data: bytes) -> tuple[int, int, str, tuple[float, ...]]:
    """(sec, nanosec, frame_id, the six velocities) of a TwistStamped."""
    assert data[:2] == b"\x00\x01"
    body = data[4:]
    sec, nanosec, n = struct.unpack_from("<iII", body, 0)
    frame_id = body[12 : 12 + n - 1].decode()
    at = 12 + n
    at += -at % 8
    return sec, nanosec, frame_id, struct.unpack_from("<6d", body, at)
