"""MCAP session files: the writer the recorder streams into, the reader replay and
``--recover`` use, and the calibration a recording carries.

A session is chunked (lz4 by default: the frames' pixels are compressed already, see
:mod:`~ovis.common.recording.frames`; zstd or none on request) and indexed at the end
(chunk and message indexes, statistics, summary) when it is closed. Until then every
finished chunk is on disk, so a recorder killed outright leaves a file that reads up to
its last complete chunk: :class:`SessionReader` reads records in order (MCAP's stream
reading, no index needed) and stops there, and :func:`recover` rewrites such a file
with its index.
"""

from __future__ import annotations

import contextlib
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass
from importlib import metadata as dist_metadata
from pathlib import Path
from typing import Any, BinaryIO, NamedTuple

import msgspec
from mcap.exceptions import EndOfFile
from mcap.reader import SeekingReader
from mcap.records import Channel, Message, Metadata, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer

from ovis.common.atomic import open_atomic
from ovis.common.calibration.file import Calibration
from ovis.common.messages import CalibrationUpdate, MessageError, decode
from ovis.common.recording.foxglove import foxglove_schema
from ovis.common.recording.frames import PACKED_CODEC, PackedFrame, pack_frame, unpack_frame
from ovis.common.recording.schemas import bus_type, schema_bytes

__all__ = [
    "BUS_ENCODING",
    "COMPRESSIONS",
    "RecordedMessage",
    "RecordingError",
    "SessionReader",
    "SessionWriter",
    "TopicStats",
    "recorded_calibration",
    "recover",
]

#: message_encoding of the bus channels (payloads exactly as they travel).
BUS_ENCODING = "msgpack"
COMPRESSIONS = {
    "lz4": CompressionType.LZ4,
    "zstd": CompressionType.ZSTD,
    "none": CompressionType.NONE,
}
CHUNK_SIZE = 1 << 20
_MAGIC = b"\x89MCAP0\r\n"


class RecordingError(ValueError):
    """A session file that cannot be read or written; the text says why and what to do."""


def _library() -> str:
    with contextlib.suppress(dist_metadata.PackageNotFoundError):
        return f"ovis {dist_metadata.version('ovis')}, mcap {dist_metadata.version('mcap')}"
    return "ovis"


@dataclass
class TopicStats:
    """What has been written on one topic."""

    messages: int = 0
    bytes: int = 0


class SessionWriter:
    """Streams messages into an MCAP file: bus payloads (msgpack, with their message's
    JSON Schema) and Foxglove views (JSON). Not thread-safe: one writer thread."""

    def __init__(
        self,
        path: Path | str,
        *,
        compression: str = "lz4",
        chunk_size: int = CHUNK_SIZE,
        metadata: dict[str, str] | None = None,
        stream: BinaryIO | None = None,
    ) -> None:
        if compression not in COMPRESSIONS:
            raise RecordingError(
                f"compression {compression!r}: choose one of {', '.join(COMPRESSIONS)}"
            )
        self.path = Path(path)
        self._own = stream is None
        try:
            self._fh: BinaryIO = stream if stream is not None else open(self.path, "wb")  # noqa: SIM115
        except OSError as exc:
            raise RecordingError(f"cannot write {self.path}: {exc.strerror}") from None
        self._writer = Writer(
            self._fh, chunk_size=chunk_size, compression=COMPRESSIONS[compression]
        )
        self._writer.start(profile="", library=_library())
        if metadata:
            self._writer.add_metadata("ovis", metadata)
        self._schemas: dict[tuple[str, str], int] = {}
        self._channels: dict[tuple[str, str, str], int] = {}
        self.stats: dict[str, TopicStats] = {}
        self.closed = False
        self._size = 0

    def channel(
        self,
        topic: str,
        message_encoding: str,
        schema_name: str,
        schema_encoding: str,
        schema_data: bytes,
        metadata: dict[str, str] | None = None,
    ) -> int:
        """The id of a channel, registered on first use (its schema too)."""
        key = (topic, message_encoding, schema_name)
        cid = self._channels.get(key)
        if cid is None:
            sid = self._schemas.get((schema_name, schema_encoding))
            if sid is None:
                sid = self._writer.register_schema(schema_name, schema_encoding, schema_data)
                self._schemas[(schema_name, schema_encoding)] = sid
            cid = self._writer.register_channel(topic, message_encoding, sid, metadata or {})
            self._channels[key] = cid
        return cid

    def write(self, channel_id: int, topic: str, data: bytes, log_ns: int, publish_ns: int) -> None:
        """One message; the file is flushed so that every finished chunk is on disk."""
        self._writer.add_message(channel_id, log_ns, data, publish_ns)
        st = self.stats.setdefault(topic, TopicStats())
        st.messages += 1
        st.bytes += len(data)
        self._fh.flush()

    def bus(self, key: str, payload: bytes, log_ns: int, publish_ns: int) -> None:
        """A bus message as it travelled on Zenoh key ``key``."""
        name, tp = bus_type(key)
        cid = self._channels.get((key, BUS_ENCODING, name))
        if cid is None:
            cid = self.channel(
                key,
                BUS_ENCODING,
                name,
                "jsonschema",
                schema_bytes(tp, name),
                {"zenoh.key": key, "zenoh.encoding": "application/msgpack"},
            )
        self.write(cid, key, payload, log_ns, publish_ns)

    def frame(self, key: str, payload: bytes, log_ns: int, publish_ns: int) -> None:
        """A frame that travelled on ``key``, its pixels compressed losslessly
        (:func:`~ovis.common.recording.frames.pack_frame`) when it can be rebuilt
        bit-exact, else as it came."""
        packed = pack_frame(payload)
        if packed is None:
            self.bus(key, payload, log_ns, publish_ns)
            return
        cid = self._channels.get((key, BUS_ENCODING, "ovis.PackedFrame"))
        if cid is None:
            cid = self.channel(
                key,
                BUS_ENCODING,
                "ovis.PackedFrame",
                "jsonschema",
                schema_bytes(PackedFrame, "ovis.PackedFrame"),
                {
                    "zenoh.key": key,
                    "zenoh.encoding": "application/msgpack",
                    "ovis.codec": PACKED_CODEC,
                },
            )
        self.write(cid, key, packed, log_ns, publish_ns)

    def view(
        self, topic: str, schema_name: str, message: Any, log_ns: int, publish_ns: int
    ) -> None:
        """A Foxglove view (JSON) such as ``foxglove.SceneUpdate``."""
        cid = self._channels.get((topic, "json", schema_name))
        if cid is None:
            cid = self.channel(
                topic, "json", schema_name, "jsonschema", foxglove_schema(schema_name)
            )
        self.write(cid, topic, msgspec.json.encode(message), log_ns, publish_ns)

    def add_metadata(self, name: str, values: dict[str, str]) -> None:
        """A named set of strings (the recorder writes "ovis": arena, start, options)."""
        self._writer.add_metadata(name, values)

    def bytes_written(self) -> int:
        """Bytes in the file so far (its size once closed)."""
        return self._size if self.closed else self._fh.tell()

    def close(self) -> None:
        """Write the last chunk, the index and the summary; close the file."""
        if self.closed:
            return
        self._writer.finish()
        self._size = self._fh.tell()
        self.closed = True
        if self._own:
            self._fh.close()


class RecordedMessage(NamedTuple):
    """One message of a session with its channel and schema records."""

    channel: Channel
    schema: Schema | None
    message: Message

    @property
    def topic(self) -> str:
        return self.channel.topic

    @property
    def is_bus(self) -> bool:
        return self.channel.message_encoding == BUS_ENCODING

    @property
    def log_ns(self) -> int:
        return self.message.log_time

    @property
    def data(self) -> bytes:
        """The bytes stored in the file."""
        return self.message.data

    def payload(self) -> bytes:
        """The payload as it travelled on the bus (a packed frame is rebuilt bit-exact);
        :class:`~ovis.common.messages.MessageError` if a packed frame is damaged."""
        if self.channel.metadata.get("ovis.codec") == PACKED_CODEC:
            return unpack_frame(self.message.data)
        return self.message.data


class SessionReader:
    """Reads a session in file order with MCAP's stream reader: no index needed, so a
    file cut short (a recorder killed outright) reads up to its last complete chunk;
    ``cut`` then says where it ended. A file that is not MCAP, or is damaged before its
    end, raises :class:`RecordingError`."""

    def __init__(self, path: Path | str) -> None:
        self.path = Path(path)
        self.cut: str | None = None
        self.messages_read = 0
        self.metadata: dict[str, dict[str, str]] = {}
        #: the schema and channel records read so far, by id
        self.schemas: dict[int, Schema] = {}
        self.channels: dict[int, Channel] = {}
        self.complete = False
        if not self.path.is_file():
            raise RecordingError(f"{self.path} does not exist (or is not a file)")
        with open(self.path, "rb") as fh:
            head = fh.read(len(_MAGIC))
        if head != _MAGIC:
            raise RecordingError(
                f"{self.path} is not an MCAP recording (it does not start with the MCAP "
                "magic bytes); record one with `ovis record`"
            )

    def __iter__(self) -> Iterator[RecordedMessage]:
        size = self.path.stat().st_size
        schemas, channels = self.schemas, self.channels
        with open(self.path, "rb") as fh:
            records = StreamReader(fh, validate_crcs=True, record_size_limit=size).records
            while True:
                try:
                    record = next(records)
                except StopIteration:
                    self.complete = True
                    return
                except Exception as exc:  # zstd, lz4, struct, CRC, MCAP: all mean damage
                    if isinstance(exc, EndOfFile) or fh.tell() >= size:
                        self.cut = (
                            f"{self.path} was cut short (no index at its end: a recorder "
                            f"killed outright?); read {self.messages_read} messages, up to "
                            "its last complete chunk"
                        )
                        return
                    raise RecordingError(
                        f"{self.path} is damaged near byte {fh.tell()} of {size} "
                        f"({type(exc).__name__}: {exc}); `ovis record --recover` keeps the "
                        "messages before the damage"
                    ) from None
                if isinstance(record, Schema):
                    schemas[record.id] = record
                elif isinstance(record, Channel):
                    channels[record.id] = record
                elif isinstance(record, Metadata):
                    self.metadata[record.name] = dict(record.metadata)
                elif isinstance(record, Message):
                    channel = channels.get(record.channel_id)
                    if channel is None:
                        raise RecordingError(
                            f"{self.path}: a message names channel {record.channel_id}, which "
                            "no channel record declares before it"
                        )
                    self.messages_read += 1
                    yield RecordedMessage(channel, schemas.get(channel.schema_id), record)

    def bus_messages(self, topics: set[str] | None = None) -> Iterator[RecordedMessage]:
        """The bus messages (those replay can publish), optionally of ``topics`` only."""
        for rec in self:
            if rec.is_bus and (topics is None or rec.topic in topics):
                yield rec


@dataclass
class RecoverReport:
    """What :func:`recover` kept."""

    messages: int
    topics: dict[str, int]
    was_cut: bool
    note: str


def recover(source: Path | str, target: Path | str, *, compression: str = "lz4") -> RecoverReport:
    """Rewrite ``source`` (a session cut short, or damaged) as a complete, indexed
    session ``target`` holding every message that reads back; ``target`` appears only
    once it is complete."""
    reader = SessionReader(source)
    counts: Counter[str] = Counter()
    note = ""
    with open_atomic(target) as fh:
        writer = SessionWriter(target, compression=compression, stream=fh)
        ids: dict[int, int] = {}
        try:
            for rec in reader:
                cid = ids.get(rec.channel.id)
                if cid is None:
                    s = rec.schema
                    cid = ids[rec.channel.id] = writer.channel(
                        rec.topic,
                        rec.channel.message_encoding,
                        s.name if s else "",
                        s.encoding if s else "",
                        s.data if s else b"",
                        dict(rec.channel.metadata),
                    )
                writer.write(cid, rec.topic, rec.data, rec.log_ns, rec.message.publish_time)
                counts[rec.topic] += 1
        except RecordingError as exc:
            note = str(exc)
        for name, values in reader.metadata.items():
            writer.add_metadata(name, values)
        writer.close()
    return RecoverReport(
        messages=sum(counts.values()),
        topics=dict(counts),
        was_cut=reader.cut is not None,
        note=note or reader.cut or f"{source} was complete",
    )


def recorded_calibration(path: Path | str) -> Calibration | None:
    """The newest calibration a session carries (the recorder writes the one in use when
    it starts, then every update), or None."""
    found: Calibration | None = None
    for data in _calibration_payloads(Path(path)):
        try:
            update = decode(data, CalibrationUpdate)
        except MessageError:
            continue
        if found is None or update.calibration.version >= found.version:
            found = update.calibration
    return found


def _calibration_payloads(path: Path) -> Iterator[bytes]:
    """The payloads of the calibration topics: through the index of a complete file
    (only the chunks that hold them), else by reading the whole file."""
    reader = SessionReader(path)
    try:
        with open(path, "rb") as fh:
            indexed = SeekingReader(fh)
            summary = indexed.get_summary()
            if summary is not None and summary.chunk_indexes:
                topics = [
                    c.topic
                    for c in summary.channels.values()
                    if c.topic.endswith("/calibration") and c.message_encoding == BUS_ENCODING
                ]
                payloads = [m.data for _, _, m in indexed.iter_messages(topics=topics)]
                yield from payloads
                return
    except Exception:  # no or damaged index: read in order
        pass
    for rec in reader.bus_messages():
        if rec.topic.endswith("/calibration"):
            yield rec.data
