"""ROS 2 images in (:mod:`ovis.common.ros2.images`) and the bridge's topic rules
(:mod:`ovis.common.ros2.topics`), on a real photo."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from real_photos import photo_paths
from rosbags.typesys import Stores, get_typestore

from ovis.common.ros2.images import COMPRESSED, RAW, ImageError, image_from_cdr
from ovis.common.ros2.topics import KEPT, STREAM, qos_of, topic_kind

TS = get_typestore(Stores.ROS2_JAZZY)
T = TS.types


def _header(stamp_ns: int):
    time = T["builtin_interfaces/msg/Time"](sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9)
    return T["std_msgs/msg/Header"](stamp=time, frame_id="cam")


def _raw(data: np.ndarray, rows: int, cols: int, encoding: str, step: int, big: int = 0) -> bytes:
    msg = T[RAW](header=_header(5), height=rows, width=cols, encoding=encoding,
                 is_bigendian=big, step=step, data=data.ravel().view(np.uint8))  # fmt: skip
    return bytes(TS.serialize_cdr(msg, RAW))


def test_a_real_photo_arrives_as_it_left() -> None:
    grey = cv2.imread(str(photo_paths()[0]), cv2.IMREAD_GRAYSCALE)
    rows, cols = grey.shape
    png = cv2.imencode(".png", grey)[1].ravel()
    cdr = bytes(TS.serialize_cdr(T[COMPRESSED](header=_header(1_700_000_000_5), format="png",
                                               data=png), COMPRESSED))  # fmt: skip
    image, stamp = image_from_cdr(cdr, COMPRESSED)
    assert stamp == 1_700_000_000_5 and np.array_equal(image, grey)
    padded = np.zeros((rows, cols + 16), np.uint8)  # a step longer than a row
    padded[:, :cols] = grey
    assert np.array_equal(
        image_from_cdr(_raw(padded, rows, cols, "mono8", cols + 16), RAW)[0], grey
    )
    rgb = np.dstack([grey, grey // 2, grey // 3])
    bgr = image_from_cdr(_raw(rgb, rows, cols, "rgb8", cols * 3), RAW)[0]
    assert np.array_equal(bgr, rgb[:, :, ::-1])
    wide = (grey.astype(np.uint16) << 8).astype(">u2")  # big-endian: its high byte is the photo
    assert np.array_equal(
        image_from_cdr(_raw(wide, rows, cols, "mono16", cols * 2, 1), RAW)[0], grey
    )


def test_images_ovis_cannot_read_say_why() -> None:
    with pytest.raises(ImageError, match="encoding 'bayer_rggb8' not read"):
        image_from_cdr(_raw(np.zeros(4, np.uint8), 2, 2, "bayer_rggb8", 2), RAW)
    with pytest.raises(ImageError, match="step 1"):
        image_from_cdr(_raw(np.zeros(4, np.uint8), 2, 2, "mono8", 1), RAW)
    with pytest.raises(ImageError, match="does not decode"):
        image_from_cdr(b"\x00\x01\x00\x00\x01", COMPRESSED)
    with pytest.raises(ImageError, match="is not an image"):
        image_from_cdr(b"", "std_msgs/msg/String")


def test_topic_rules() -> None:
    topics = ("robots/robot_3/odom", "/tf_static", "camera/image/compressed", "robots/3/pose")
    assert [topic_kind(t) for t in topics] == ["odom", "tf_static", "image", "robots/3/pose"]
    assert qos_of("/tf_static") == qos_of("camera/camera_info") == KEPT
    assert qos_of("robots/robot_3/odom") == qos_of("markers") == STREAM
    assert (KEPT.durability, KEPT.depth, STREAM.durability, STREAM.depth) == (1, 1, 2, 10)
