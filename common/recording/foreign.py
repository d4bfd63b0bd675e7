"""MCAP files written by other tools: their image channels found, and each image decoded
into the pixels an ovis frame carries (grey or BGR uint8).

Read: ``foxglove.CompressedImage`` and ``foxglove.RawImage`` (``json`` encoding, or
``protobuf`` decoded with the FileDescriptorSet the file carries, by
mcap-protobuf-support), ROS 2 ``sensor_msgs/msg/CompressedImage`` and
``sensor_msgs/msg/Image`` (``cdr``, decoded by rosbags with the ``ros2msg`` definition the
file carries, else its own). Compressed images: JPEG or PNG; raw ones: ``mono8``
(``8UC1``), ``bgr8`` (``8UC3``) or ``rgb8``. Anything else is refused with what ovis reads.

A frame's stamp is its message's log time (what replay paces by, as for ovis's own
recordings) and its ``source`` names the file and the topic.
"""

from __future__ import annotations

import contextlib
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import cv2
import msgspec
import numpy as np
from mcap.reader import SeekingReader
from mcap.records import Channel, Schema
from numpy.typing import NDArray

from ovis.common.messages import MAX_IMAGE_SIDE, Frame, FrameHeader, MessageError, decode, encode
from ovis.common.recording.session import (
    BUS_ENCODING,
    RecordedMessage,
    RecordingError,
    SessionReader,
)
from ovis.common.vision.imageio import to_uint8

__all__ = [
    "IMAGE_CHANNELS",
    "ChannelInfo",
    "ForeignError",
    "ForeignFrames",
    "ImageDecoder",
    "choose_channel",
    "compressed_pixels",
    "first_image",
    "frame_size",
    "list_channels",
    "raw_pixels",
]

#: (schema name, message encoding) of the image channels ovis reads → compressed or raw.
IMAGE_CHANNELS: dict[tuple[str, str], str] = {
    ("foxglove.CompressedImage", "json"): "compressed",
    ("foxglove.CompressedImage", "protobuf"): "compressed",
    ("foxglove.RawImage", "json"): "raw",
    ("foxglove.RawImage", "protobuf"): "raw",
    ("sensor_msgs/msg/CompressedImage", "cdr"): "compressed",
    ("sensor_msgs/msg/Image", "cdr"): "raw",
}
READS = (
    "foxglove.CompressedImage or foxglove.RawImage (json or protobuf), "
    "sensor_msgs/msg/CompressedImage or sensor_msgs/msg/Image (cdr)"
)
#: raw encodings (lower case) → channels, and the conversion to BGR if any
RAW_ENCODINGS: dict[str, tuple[int, int | None]] = {
    "mono8": (1, None),
    "8uc1": (1, None),
    "bgr8": (3, None),
    "8uc3": (3, None),
    "rgb8": (3, cv2.COLOR_RGB2BGR),
}
PIXELS_READ = "raw mono8, bgr8 or rgb8 (8UC1, 8UC3), or JPEG or PNG compressed"


class ForeignError(RecordingError):
    """A file, channel or image ovis cannot read; the text says why and what it reads."""


@dataclass(frozen=True)
class ChannelInfo:
    """One channel of a file: its records and how many messages it holds (None: not
    counted in the file's summary)."""

    channel: Channel
    schema: Schema | None
    messages: int | None = None

    @property
    def topic(self) -> str:
        return self.channel.topic

    @property
    def schema_name(self) -> str:
        return self.schema.name if self.schema is not None else ""

    @property
    def encoding(self) -> str:
        return self.channel.message_encoding

    @property
    def kind(self) -> str | None:
        """ "compressed" or "raw" for an image channel ovis reads, else None."""
        return IMAGE_CHANNELS.get((self.schema_name, self.encoding))

    def describe(self) -> str:
        """``topic (schema, encoding, N messages)``."""
        count = "" if self.messages is None else f", {self.messages} messages"
        return (
            f"{self.topic} ({self.schema_name or 'no schema'}, "
            f"{self.encoding or 'no encoding'}{count})"
        )


def list_channels(path: Path | str) -> list[ChannelInfo]:
    """Every channel of an MCAP file: from its summary when it has one, else by reading
    it through (a file cut short). :class:`RecordingError` if it is not MCAP."""
    path = Path(path)
    SessionReader(path)  # not a file, or not MCAP: say so
    try:
        with open(path, "rb") as fh:
            summary = SeekingReader(fh).get_summary()
    except Exception:  # no summary or a damaged one: read the file in order
        summary = None
    if summary is not None and summary.channels:
        stats = summary.statistics
        return [
            ChannelInfo(
                c,
                summary.schemas.get(c.schema_id),
                stats.channel_message_counts.get(c.id, 0) if stats is not None else None,
            )
            for c in summary.channels.values()
        ]
    reader = SessionReader(path)
    seen = Counter(rec.channel.id for rec in reader)
    return [
        ChannelInfo(c, reader.schemas.get(c.schema_id), seen[c.id])
        for c in reader.channels.values()
    ]


def _listing(channels: list[ChannelInfo]) -> str:
    return "; ".join(c.describe() for c in channels) or "none"


def choose_channel(path: Path | str, topic: str | None = None) -> ChannelInfo | None:
    """The image channel whose images replay publishes as frames; None for an ovis
    recording (it has bus channels and no ``topic`` was asked for: replayed as it is).
    :class:`ForeignError` naming every channel when none fits, or several do and no
    ``topic`` picks one."""
    channels = list_channels(path)
    if topic is None and any(c.encoding == BUS_ENCODING for c in channels):
        return None
    if topic is not None:
        named = [c for c in channels if c.topic == topic]
        if not named:
            raise ForeignError(
                f"{path} has no channel {topic!r}; channels found: {_listing(channels)}"
            )
        usable = [c for c in named if c.kind is not None]
        if not usable:
            raise ForeignError(
                f"channel {named[0].describe()} of {path} is not an image channel ovis "
                f"reads ({READS}); channels found: {_listing(channels)}"
            )
        return usable[0]
    usable = [c for c in channels if c.kind is not None]
    if not usable:
        raise ForeignError(
            f"{path} holds no image channel ovis reads ({READS}); channels found: "
            f"{_listing(channels)}"
        )
    if len(usable) > 1:
        raise ForeignError(
            f"{path} holds {len(usable)} image channels: pick one with --topic NAME: "
            f"{_listing(usable)}"
        )
    return usable[0]


def compressed_pixels(data: Any, fmt: str) -> NDArray[np.uint8]:
    """A JPEG or PNG image (``fmt`` as Foxglove or ROS name it: ``jpeg``, ``png``,
    ``bgr8; jpeg compressed bgr8``) as grey or BGR uint8."""
    name = fmt.lower()
    if "compresseddepth" in name or not any(k in name for k in ("jpeg", "jpg", "png")):
        raise ForeignError(f"image format {fmt!r} is not supported: ovis reads {PIXELS_READ}")
    buffer = np.frombuffer(data, dtype=np.uint8)
    try:
        image = cv2.imdecode(buffer, cv2.IMREAD_UNCHANGED) if buffer.size else None
    except cv2.error:  # OpenCV refuses some damaged data outright
        image = None
    if image is None or image.size == 0:
        raise ForeignError(f"a {fmt} image does not decode ({len(data)} bytes)")
    image = to_uint8(image)
    if image.ndim == 3 and image.shape[2] == 4:
        image = cv2.cvtColor(image, cv2.COLOR_BGRA2BGR)
    elif image.ndim == 3 and image.shape[2] == 1:
        image = image[:, :, 0]
    return image


def raw_pixels(width: int, height: int, encoding: str, step: int, data: Any) -> NDArray[np.uint8]:
    """A raw image (rows ``step`` bytes apart, padding dropped) as grey or BGR uint8."""
    spec = RAW_ENCODINGS.get(encoding.lower())
    if spec is None:
        raise ForeignError(
            f"raw image encoding {encoding!r} is not supported: ovis reads {PIXELS_READ}"
        )
    channels, to_bgr = spec
    if not (1 <= width <= MAX_IMAGE_SIDE and 1 <= height <= MAX_IMAGE_SIDE):
        raise ForeignError(f"a raw image of {width}x{height} pixels: each side must be 1 to "
                           f"{MAX_IMAGE_SIDE}")  # fmt: skip
    row = width * channels
    step = step or row
    pixels = np.frombuffer(data, dtype=np.uint8)
    if step < row or pixels.size < step * height:
        raise ForeignError(
            f"a {width}x{height} {encoding} image with rows of {step} bytes holds "
            f"{pixels.size} bytes: it needs rows of at least {row} bytes and "
            f"{step * height} bytes in all"
        )
    image = pixels[: step * height].reshape(height, step)[:, :row]
    image = image.reshape(height, width, channels) if channels == 3 else image
    if to_bgr is not None:
        return cv2.cvtColor(image, to_bgr)
    return np.ascontiguousarray(image)


class _Compressed(msgspec.Struct):
    """The fields ovis reads of a JSON ``foxglove.CompressedImage`` (data in base64)."""

    data: bytes
    format: str


class _Raw(msgspec.Struct):
    """The fields ovis reads of a JSON ``foxglove.RawImage`` (data in base64)."""

    width: int
    height: int
    encoding: str
    data: bytes
    step: int = 0


def _json_decoder(info: ChannelInfo) -> Callable[[bytes], Any]:
    tp = _Compressed if info.kind == "compressed" else _Raw
    return msgspec.json.Decoder(tp).decode


def _protobuf_decoder(info: ChannelInfo) -> Callable[[bytes], Any]:
    """The message class the channel's FileDescriptorSet defines, as mcap-protobuf-support
    builds it."""
    from mcap_protobuf.decoder import DecoderFactory

    decoder = DecoderFactory().decoder_for("protobuf", info.schema)
    if decoder is None:
        raise ValueError("its schema is not a protobuf FileDescriptorSet")
    return decoder


def _ros2_decoder(info: ChannelInfo) -> Callable[[bytes], Any]:
    """rosbags' CDR deserializer, with the message definition the file carries (its
    ``ros2msg`` text), else rosbags' own definitions of the latest ROS 2."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    schema = info.schema
    if schema is not None and schema.encoding == "ros2msg" and schema.data:
        store = get_typestore(Stores.EMPTY)
        store.register(get_types_from_msg(schema.data.decode(), info.schema_name))
    else:
        store = get_typestore(Stores.LATEST)
    return partial(store.deserialize_cdr, typename=info.schema_name)


_DECODERS = {"json": _json_decoder, "protobuf": _protobuf_decoder, "cdr": _ros2_decoder}


class ImageDecoder:
    """The pixels of each message of one image channel."""

    def __init__(self, info: ChannelInfo) -> None:
        if info.kind is None:
            raise ForeignError(f"{info.describe()} is not an image channel ovis reads ({READS})")
        self.info = info
        try:
            self._decode = _DECODERS[info.encoding](info)
        except Exception as exc:  # the libraries' errors on a schema they cannot use
            raise ForeignError(
                f"the schema of {info.describe()} cannot be used: {type(exc).__name__}: {exc}"
            ) from None

    def __call__(self, data: bytes) -> NDArray[np.uint8]:
        """The image of one message; :class:`ForeignError` saying why not."""
        try:
            m = self._decode(data)
        except Exception as exc:  # any decoder's error on a damaged message
            raise ForeignError(
                f"a message on {self.info.topic} is not a valid {self.info.schema_name} "
                f"({self.info.encoding}): {type(exc).__name__}: {exc}"
            ) from None
        if self.info.kind == "compressed":
            return compressed_pixels(m.data, m.format)
        return raw_pixels(m.width, m.height, m.encoding, m.step, m.data)


def _messages_of(reader: SessionReader, info: ChannelInfo) -> Iterator[RecordedMessage]:
    return (rec for rec in reader if rec.channel.id == info.channel.id)


def first_image(path: Path | str, info: ChannelInfo) -> NDArray[np.uint8]:
    """The image of the channel's first message (checked before a replay starts)."""
    for rec in _messages_of(SessionReader(path), info):
        return ImageDecoder(info)(rec.data)
    raise ForeignError(f"{info.describe()} of {path} holds no message")


def frame_size(path: Path | str, topic: str | None = None) -> tuple[int, int] | None:
    """(width, height) of the first frame a replay of ``path`` publishes: the first
    image of its image channel, or an ovis recording's first recorded frame (None: it
    has none)."""
    info = choose_channel(path, topic)
    if info is not None:
        image = first_image(path, info)
        return image.shape[1], image.shape[0]
    for rec in SessionReader(path).bus_messages():
        if rec.topic.endswith("/frames"):
            with contextlib.suppress(MessageError):
                header = decode(rec.payload(), FrameHeader)
                return header.cols, header.rows
    return None


class ForeignFrames:
    """The images of one channel as ovis frame payloads for ``key``: sequence numbers
    in the channel's message order, stamped with each message's log time."""

    def __init__(self, path: Path | str, info: ChannelInfo, key: str, stream: str = "") -> None:
        self.info = info
        self.key = key
        self.stream = stream
        self.source = f"{path} {info.topic}"
        self.decoder = ImageDecoder(info)

    def messages(self, reader: SessionReader) -> Iterator[tuple[int, str, Callable[[], bytes]]]:
        """(log time, key, the frame's payload: :class:`ForeignError` if its image cannot
        be read) for each message of the channel, in file order."""
        for seq, rec in enumerate(_messages_of(reader, self.info)):
            yield rec.log_ns, self.key, partial(self._payload, rec, seq)

    def _payload(self, rec: RecordedMessage, seq: int) -> bytes:
        image = self.decoder(rec.data)
        stamp = rec.log_ns or rec.message.publish_time
        frame = Frame.from_image(
            image, seq=seq, stamp_ns=stamp, source=self.source, copy=False, stream=self.stream
        )
        return encode(frame)
