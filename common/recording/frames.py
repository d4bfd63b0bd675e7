"""Frames in a recording: the pixels compressed losslessly, restored bit-exact.

A raw frame is mostly pixels. The recorder stores it as a :class:`PackedFrame` (the same
fields, the pixels compressed with zstd at its fastest level) and replay rebuilds the
exact payload that travelled. Only a payload that re-encodes to itself is packed (ovis
encodes every frame the same way); any other is recorded as it came.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

import msgspec
import zstandard

from ovis.common.messages import MAX_IMAGE_SIDE, Frame, MessageError, decode, encode

__all__ = ["PACKED_CODEC", "PackedFrame", "pack_frame", "unpack_frame"]

#: Channel metadata value ("ovis.codec") of a channel of packed frames.
PACKED_CODEC = "packed-frame"
ZSTD_LEVEL = 1

Side = Annotated[int, msgspec.Meta(ge=1, le=MAX_IMAGE_SIDE)]


class PackedFrame(msgspec.Struct, tag_field="type", tag="packed-frame", kw_only=True):
    """A :class:`~ovis.common.messages.Frame` whose ``data`` is zstd-compressed
    (``pixels``)."""

    seq: Annotated[int, msgspec.Meta(ge=0)]
    stamp_ns: Annotated[int, msgspec.Meta(ge=0)]
    rows: Side
    cols: Side
    channels: Literal[1, 3] = 1
    dtype: Literal["uint8"] = "uint8"
    source: str = ""
    codec: Literal["zstd"] = "zstd"
    pixels: bytes


#: The fields a packed frame shares with a frame (all but the pixels).
_HEADER = ("seq", "stamp_ns", "rows", "cols", "channels", "dtype", "source")


def _header(message: Frame | PackedFrame) -> dict[str, Any]:
    return {name: getattr(message, name) for name in _HEADER}


def pack_frame(payload: bytes) -> bytes | None:
    """The packed form of a frame payload, or None when it cannot be rebuilt bit-exact
    (not a valid frame, or encoded otherwise than ovis encodes frames)."""
    try:
        frame = decode(payload, Frame)
    except MessageError:
        return None
    if encode(frame) != payload:
        return None
    pixels = zstandard.ZstdCompressor(level=ZSTD_LEVEL).compress(frame.data)
    return encode(PackedFrame(**_header(frame), pixels=pixels))


def unpack_frame(data: bytes) -> bytes:
    """The frame payload exactly as it travelled; :class:`MessageError` if ``data`` is
    not a packed frame whose pixels fill its size."""
    try:
        packed = msgspec.msgpack.decode(data, type=PackedFrame)
    except (msgspec.ValidationError, msgspec.DecodeError) as exc:
        raise MessageError(f"not a packed frame: {exc}") from None
    size = packed.rows * packed.cols * packed.channels
    try:
        pixels = zstandard.ZstdDecompressor().decompress(packed.pixels, max_output_size=size)
    except zstandard.ZstdError as exc:
        raise MessageError(f"packed frame {packed.seq}: pixels do not decompress: {exc}") from None
    try:
        frame = Frame(**_header(packed), data=pixels)
    except ValueError as exc:
        raise MessageError(f"packed frame {packed.seq}: {exc}") from None
    return encode(frame)
