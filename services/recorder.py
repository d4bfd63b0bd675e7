"""The recorder behind ``ovis record``: Zenoh subscribers put every sample of the chosen
topics in a queue (never blocking Zenoh, never dropping), one thread writes them into
the session file, with the Foxglove views of frames and obstacles beside them, and with
``ros2`` the same data as ROS 2 messages (:mod:`ovis.common.ros2`) into a rosbag2 bag
beside it (:mod:`ovis.common.ros2.bag`) that ``ros2 bag play`` and rosbags read."""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import zenoh

from ovis.common.messages import (
    CalibrationUpdate,
    Frame,
    FrameHeader,
    MessageError,
    ObstacleFrame,
    Topics,
    decode,
)
from ovis.common.recording.foxglove import compressed_image, scene_update
from ovis.common.recording.pacing import FrameGate
from ovis.common.recording.session import SessionWriter
from ovis.common.ros2.bag import RosBag
from ovis.common.ros2.convert import RosMessage
from ovis.common.ros2.stream import RosStream

__all__ = ["Recorder", "topic_keys"]

log = logging.getLogger("ovis.record")


def topic_keys(topics: Topics, patterns: list[str] | None) -> list[str]:
    """Key expressions to record: each pattern as given if it starts with ``ovis/``,
    else under the arena's root (``obstacles`` → ``ovis/<arena>/obstacles``); default
    everything of the arena."""
    if not patterns:
        return [f"{topics.root}/**"]
    return [p if p.startswith("ovis/") else f"{topics.root}/{p.lstrip('/')}" for p in patterns]


def _stamp_ns(ts: zenoh.Timestamp | None, default: int) -> int:
    """A Zenoh timestamp (set by a router on the way) in ns since the Unix epoch;
    ``default`` without one."""
    if ts is None:
        return default
    try:
        return int(ts.get_time_as_ntp64().as_nanos())
    except (ValueError, OverflowError, AttributeError):
        return default


@dataclass
class RecorderCounts:
    """What the recorder saw, beyond what it wrote (``SessionWriter.stats``)."""

    received: int = 0
    frames_skipped: int = 0  # left out by --frames
    frames_missed: int = 0  # gaps in the frames' sequence numbers (dropped upstream)
    view_errors: int = 0
    ros2_errors: int = 0  # messages that could not be converted to ROS 2
    backlog_max: int = 0
    last_error: str = ""
    by_topic: dict[str, int] = field(default_factory=dict)


class Recorder:
    """Subscribes ``keys`` on ``session`` and writes what comes into ``writer``."""

    def __init__(
        self,
        session: zenoh.Session,
        writer: SessionWriter,
        topics: Topics,
        keys: list[str],
        *,
        frames: FrameGate,
        views: bool = True,
        ros2: RosStream | None = None,
        bag: RosBag | None = None,
    ) -> None:
        if (ros2 is None) != (bag is None):
            raise ValueError("the ROS 2 stream and its bag go together")
        self.session = session
        self.ros2 = ros2
        self.bag = bag
        self.writer = writer
        self.topics = topics
        self.gate = frames
        self.views = views
        self.counts = RecorderCounts()
        self._queue: queue.SimpleQueue[tuple[str, bytes, int, int] | None] = queue.SimpleQueue()
        self._last_seq: int | None = None
        self._closed = threading.Event()
        self.calibration_recorded = False
        self._thread = threading.Thread(target=self._drain, name="recorder-writer", daemon=True)
        self._thread.start()
        self._subs = [session.declare_subscriber(k, self._on_sample) for k in keys]
        self.keys = keys

    def _on_sample(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        if key == self.topics.calibration:
            self.calibration_recorded = True
        now = time.time_ns()
        self._queue.put((key, sample.payload.to_bytes(), now, _stamp_ns(sample.timestamp, now)))

    def follow_calibration(self, period_s: float = 1.0) -> None:
        """Ask the calibrator for the calibration in use until it answers, and record it:
        a session then carries the calibration its frames were processed with, even one
        published before the recording started (later updates are recorded as they are
        published). Runs in the background until answered or closed."""

        def ask() -> None:
            while not self._closed.is_set() and not self.calibration_recorded:
                try:
                    replies = list(self.session.get(self.topics.calibration, timeout=period_s))
                except zenoh.ZError:  # the session is closing
                    return
                for reply in replies:
                    if reply.ok is not None and not self._closed.is_set():
                        now = time.time_ns()
                        payload = reply.ok.payload.to_bytes()
                        self._queue.put((self.topics.calibration, payload, now, now))
                        self.calibration_recorded = True
                        return
                self._closed.wait(period_s)

        threading.Thread(target=ask, name="recorder-calibration", daemon=True).start()

    def backlog(self) -> int:
        return self._queue.qsize()

    def _drain(self) -> None:
        while True:
            item = self._queue.get()
            if item is None:
                return
            self.counts.backlog_max = max(self.counts.backlog_max, self._queue.qsize())
            try:
                self.write_sample(*item)
            except Exception as exc:  # a message that cannot be written must not stop the rest
                self.counts.last_error = f"{type(exc).__name__}: {exc}"
                log.warning("could not record a message on %s: %s", item[0], exc)

    def write_sample(self, key: str, payload: bytes, log_ns: int, published_ns: int) -> None:
        """Write one received sample (what the writer thread does with each)."""
        c = self.counts
        c.received += 1
        c.by_topic[key] = c.by_topic.get(key, 0) + 1
        w = self.writer
        if key == self.topics.frames:
            try:
                header = decode(payload, FrameHeader)
            except MessageError:
                w.bus(key, payload, log_ns, published_ns)  # kept as it came
                return
            if self._last_seq is not None and header.seq > self._last_seq + 1:
                c.frames_missed += header.seq - self._last_seq - 1
            self._last_seq = header.seq
            if not self.gate.keep(header.stamp_ns):
                c.frames_skipped += 1
                return
            w.frame(key, payload, log_ns, published_ns)
            if self.ros2 is not None:
                self._ros2(payload, Frame, self.ros2.images_due, log_ns)
            if self.views:
                self._view(
                    f"/{self.topics.root}/image",
                    "foxglove.CompressedImage",
                    payload,
                    Frame,
                    compressed_image,
                    log_ns,
                )
            return
        w.bus(key, payload, log_ns, published_ns)
        if self.ros2 is not None and key == self.topics.obstacles:
            self._ros2(payload, ObstacleFrame, self.ros2.obstacles, log_ns)
        if self.ros2 is not None and key == self.topics.calibration:
            self._ros2(
                payload,
                CalibrationUpdate,
                lambda u: self.ros2.calibration(u.calibration, log_ns),
                log_ns,
            )
        if self.views and key == self.topics.obstacles:
            self._view(
                f"/{self.topics.root}/scene",
                "foxglove.SceneUpdate",
                payload,
                ObstacleFrame,
                scene_update,
                log_ns,
            )

    def _view(
        self,
        topic: str,
        schema: str,
        payload: bytes,
        tp: Any,
        convert: Callable[[Any], Any],
        log_ns: int,
    ) -> None:
        """Also write the Foxglove view of a message (one that does not decode is
        counted, and recorded all the same on its bus channel)."""
        try:
            msg = decode(payload, tp)
            view = convert(msg)
        except (MessageError, ValueError) as exc:
            self.counts.view_errors += 1
            self.counts.last_error = str(exc)
            return
        self.writer.view(topic, schema, view, log_ns, msg.stamp_ns)

    def _ros2(
        self, payload: bytes, tp: Any, convert: Callable[[Any], list[RosMessage]], log_ns: int
    ) -> None:
        """Also write a message as ROS 2 messages into the bag, each on its topic (one
        that does not convert is counted, and recorded all the same on its bus
        channel)."""
        assert self.ros2 is not None and self.bag is not None
        try:
            messages = convert(decode(payload, tp))
        except (MessageError, ValueError) as exc:
            self.counts.ros2_errors += 1
            self.counts.last_error = str(exc)
            return
        for m in messages:
            self.bag.write(self.ros2.topic(m), m, log_ns)

    def close(self) -> None:
        """Stop listening, write what is queued, then the index; close the file."""
        self._closed.set()
        for sub in self._subs:
            sub.undeclare()
        self._queue.put(None)
        self._thread.join()
        try:
            self.writer.close()
        finally:
            if self.bag is not None:
                self.bag.close()
