"""The rmw_zenoh wire layout (:mod:`ovis.common.ros2.wire`) against the examples of
rmw_zenoh's design document (quoted in ``tests/rmw_zenoh_design.py``, with its source)."""

from __future__ import annotations

import struct

import pytest
import rmw_zenoh_design as design
from rosbags.typesys import Stores, get_typestore

from ovis.common.ros2 import wire


def test_data_keys_are_the_documents_examples() -> None:
    typestore = get_typestore(Stores.ROS2_JAZZY)
    assert typestore.hash_rihs01("std_msgs/msg/String") == design.STRING_HASH
    for (domain, name, type_name), key in design.KEY_EXAMPLES.items():
        made = wire.topic_key(domain, name, type_name, typestore.hash_rihs01(type_name))
        assert made == key, design.SOURCE
        assert wire.parse_topic_key(key) == wire.TopicKey(
            domain, name, type_name, design.STRING_HASH
        )
    assert wire.topic_key_pattern(3, "/ovis/camera/image/compressed") == (
        "3/ovis/camera/image/compressed/*/*"
    )


def test_tokens_are_the_documents_examples() -> None:
    node = wire.node_token(2, "aac3178e146ba6f1fc6e6a4085e77f21", 0, "/", "listener")
    assert node == design.NODE_EXAMPLE
    assert design.NODE_TOKEN.fullmatch(node)
    talker = wire.entity_token(
        "MP", 2, "8b20917502ee955ac4476e0266340d5c", 0, 10, "/", "talker", "/chatter",
        "std_msgs/msg/String", design.STRING_HASH, wire.QoS(depth=7),
    )  # fmt: skip
    assert talker == design.PUBLISHER_EXAMPLE
    listener = wire.entity_token(
        "MS", 2, "aac3178e146ba6f1fc6e6a4085e77f21", 0, 10, "/", "listener", "/chatter",
        "std_msgs/msg/String", design.STRING_HASH, wire.QoS(depth=10),
    )  # fmt: skip
    assert listener == design.SUBSCRIPTION_EXAMPLE
    back = wire.parse_token(design.PUBLISHER_EXAMPLE)
    assert (back.kind, back.node, back.topic, back.qos) == (
        "MP",
        "talker",
        "/chatter",
        wire.QoS(depth=7),
    )
    assert wire.parse_token(design.NODE_EXAMPLE).kind == "NN"


def test_namespaces_and_absolute_topics_are_mangled() -> None:
    h = design.STRING_HASH
    token = wire.entity_token(
        "MP", 0, "ab", 0, 3, "/ovis", "ovis", wire.qualified_name("/ovis", "robots/robot_3/odom"),
        "nav_msgs/msg/Odometry", h, wire.QoS(durability=wire.TRANSIENT_LOCAL, depth=1),
    )  # fmt: skip
    assert token == (
        f"@ros2_lv/0/ab/0/3/MP/%/%ovis/ovis/%ovis%robots%robot_3%odom/nav_msgs::msg::dds_::Odometry_/{h}/:1:,1:,:,:,,"
    )
    assert design.ENTITY_TOKEN.fullmatch(token)
    assert wire.qualified_name("/ovis", "/tf_static") == "/tf_static"
    assert wire.topic_key(7, "/tf_static", "tf2_msgs/msg/TFMessage", h).startswith(
        "7/tf_static/tf2_msgs::msg::dds_::TFMessage_/"
    )
    assert wire.parse_qos(":1:,1:,:,:,,") == wire.QoS(durability=1, depth=1)
    assert wire.parse_qos("2:1:2,5:,:,:,,") == wire.QoS(
        reliability=2, durability=1, history=2, depth=5
    )


@pytest.mark.parametrize(
    ("namespace", "topic"),
    [
        ("/ovis", "bad name"),
        ("/ovis", "a//b"),
        ("ovis", "x"),
        ("/ovis", "3d/x"),
        ("/ovis", "robots/3/odom"),
        ("/ovis/", ""),
    ],
)
def test_names_that_are_not_ros_names_are_refused(namespace: str, topic: str) -> None:
    with pytest.raises(wire.WireError, match="not a ROS name"):
        wire.qualified_name(namespace, topic)


def test_bad_keys_and_tokens_are_refused() -> None:
    with pytest.raises(wire.WireError):
        wire.parse_topic_key("0/chatter/String/RIHS01_00")
    with pytest.raises(wire.WireError):
        wire.parse_token(design.PUBLISHER_EXAMPLE.replace("/MP/", "/XX/"))
    with pytest.raises(wire.WireError):
        wire.parse_token(design.NODE_EXAMPLE.replace("/0/0/NN", "/0/1/NN"))
    with pytest.raises(wire.WireError):
        wire.parse_token(design.PUBLISHER_EXAMPLE.replace("::,7:,:,:,,", "::,7:,1:,:,,"))


def test_attachment_layout() -> None:
    gid = wire.entity_gid(design.PUBLISHER_EXAMPLE)
    data = wire.encode_attachment(5, 1_700_000_000_123_456_789, gid)
    # 8 + 8 + 1 + 16 bytes, little-endian, as the document lists them
    assert len(data) == 33, design.ATTACHMENT
    assert data[:8] == (5).to_bytes(8, "little")
    assert struct.unpack("<q", data[8:16])[0] == 1_700_000_000_123_456_789
    assert data[16] == 16 and data[17:] == gid
    assert wire.decode_attachment(data) == wire.Attachment(5, 1_700_000_000_123_456_789, gid)
    with pytest.raises(wire.WireError):
        wire.decode_attachment(data[:-1])
    with pytest.raises(wire.WireError):
        wire.encode_attachment(1, 1, b"short")


def test_gid_is_the_xxh3_128_of_the_token() -> None:
    # XXH3-128 of "" is 99aa06d3014798d86001c324468d497f (xxHash's reference vector):
    # low 64 bits then high 64 bits, each little-endian
    assert wire.entity_gid("") == bytes.fromhex("7f498d4624c30160d8984701d306aa99")
    assert wire.entity_gid(design.NODE_EXAMPLE) != wire.entity_gid(design.PUBLISHER_EXAMPLE)
