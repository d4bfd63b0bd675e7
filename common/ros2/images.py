"""Camera images from ROS 2: a ``sensor_msgs/msg/CompressedImage`` or
``sensor_msgs/msg/Image`` in CDR (decoded by rosbags) as the uint8 frame ovis captures
(grey or BGR), with its header's stamp."""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray
from rosbags.typesys import Stores, get_typestore

from ovis.common.vision.imageio import to_uint8

__all__ = ["COMPRESSED", "IMAGE_TYPES", "RAW", "ImageError", "image_from_cdr"]

COMPRESSED = "sensor_msgs/msg/CompressedImage"
RAW = "sensor_msgs/msg/Image"
IMAGE_TYPES = (COMPRESSED, RAW)
_TYPESTORE = get_typestore(Stores.ROS2_JAZZY)

#: sensor_msgs/Image encodings ovis reads: (channels, numpy dtype, to BGR or None)
_ENCODINGS: dict[str, tuple[int, str, int | None]] = {
    "mono8": (1, "u1", None),
    "8UC1": (1, "u1", None),
    "mono16": (1, "u2", None),
    "16UC1": (1, "u2", None),
    "bgr8": (3, "u1", None),
    "8UC3": (3, "u1", None),
    "rgb8": (3, "u1", cv2.COLOR_RGB2BGR),
    "bgra8": (4, "u1", cv2.COLOR_BGRA2BGR),
    "rgba8": (4, "u1", cv2.COLOR_RGBA2BGR),
}


class ImageError(ValueError):
    """A ROS 2 image message ovis cannot read (says why)."""


def image_from_cdr(cdr: bytes, type_name: str) -> tuple[NDArray[np.uint8], int]:
    """The frame and its header stamp (ns since the epoch; 0 when unset)."""
    if type_name not in IMAGE_TYPES:
        raise ImageError(f"{type_name} is not an image (expected {' or '.join(IMAGE_TYPES)})")
    try:
        msg = _TYPESTORE.deserialize_cdr(cdr, type_name)
    except Exception as exc:  # rosbags raises its own kinds on truncated or bad CDR
        raise ImageError(f"a {type_name} that does not decode: {exc}") from None
    stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
    if type_name == COMPRESSED:
        image = cv2.imdecode(np.asarray(msg.data, np.uint8), cv2.IMREAD_UNCHANGED)
        if image is None:
            raise ImageError(f"a CompressedImage ({msg.format!r}) that OpenCV cannot decode")
        return to_uint8(image), stamp
    return _raw(msg), stamp


def _raw(msg: object) -> NDArray[np.uint8]:
    """A sensor_msgs/Image's pixels (its step may pad each row)."""
    enc = _ENCODINGS.get(msg.encoding)  # type: ignore[attr-defined]
    if enc is None:
        known = ", ".join(_ENCODINGS)
        raise ImageError(f"image encoding {msg.encoding!r} not read (known: {known})")  # type: ignore[attr-defined]
    channels, kind, convert = enc
    rows, cols, step = msg.height, msg.width, msg.step  # type: ignore[attr-defined]
    dtype = np.dtype(kind).newbyteorder(">" if msg.is_bigendian else "<")  # type: ignore[attr-defined]
    row_bytes = cols * channels * dtype.itemsize
    data = np.asarray(msg.data, np.uint8)  # type: ignore[attr-defined]
    if rows == 0 or cols == 0 or step < row_bytes or len(data) < rows * step:
        raise ImageError(f"image {cols}x{rows} with step {step} and {len(data)} bytes of data")
    pixels = data[: rows * step].reshape(rows, step)[:, :row_bytes].copy().view(dtype)
    pixels = pixels.astype(dtype.newbyteorder("="))  # native order, as to_uint8 expects
    image = pixels.reshape(rows, cols, channels) if channels > 1 else pixels.reshape(rows, cols)
    if convert is not None:
        image = cv2.cvtColor(image, convert)
    return to_uint8(image)
