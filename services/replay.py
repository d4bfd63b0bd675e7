"""Replay behind ``ovis replay`` and ``ovis up --source SESSION.mcap``: the recorded bus
messages published again on their keys, at the recorded pace or as fast as Zenoh takes
them, frames rebuilt bit-exact (their recorded sequence numbers and stamps). A file
another tool wrote gives the images of one of its image channels as frames
(:mod:`~ovis.common.recording.foreign`), paced and stamped by their log times."""

from __future__ import annotations

import secrets
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import msgspec
import zenoh

from ovis.common.messages import ENCODING, FrameHeader, MessageError, ReplayMark, Topics, decode
from ovis.common.pipeline.stages import MAX_CLOCK_SKEW_S
from ovis.common.recording.foreign import ForeignError, ForeignFrames, choose_channel
from ovis.common.recording.pacing import Pacer, Restamp
from ovis.common.recording.session import RecordingError, SessionReader
from ovis.services.service import Service
from ovis.services.stopping import Stopping

__all__ = [
    "ONLY",
    "DeliveryCheck",
    "ReplayReport",
    "Replayer",
    "capture_from_recording",
    "is_recording",
]

#: ``--only STAGE``: the topics each stage publishes.
ONLY: dict[str, tuple[str, ...]] = {
    "capture": ("frames", "truth", "drive"),
    "preprocess": ("binary",),
    "label": ("blobs",),
    "pose": ("obstacles", "health"),
    "calibrator": ("calibration",),
    "planner": ("cmd",),
}
#: Stamps older than this are moved to now by ``--stamps auto`` (the preprocess service
#: refuses frames stamped more than MAX_CLOCK_SKEW_S away from its clock).
AUTO_RESTAMP_S = MAX_CLOCK_SKEW_S / 2
#: At most this long to wait, at the end, for the messages sent to leave the process.
FLUSH_S = 5.0


def is_recording(source: str) -> bool:
    """Whether a capture source names a session file."""
    return source.lower().endswith(".mcap")


def rebase(key: str, arena: str | None) -> str:
    """``ovis/<recorded arena>/rest`` moved to ``arena`` (None: as recorded)."""
    parts = key.split("/", 2)
    if arena is None or len(parts) < 3 or parts[0] != "ovis":
        return key
    return f"ovis/{arena}/{parts[2]}"


@dataclass
class ReplayReport:
    """What a replay published."""

    messages: int = 0
    frames: int = 0
    passes: int = 0
    by_topic: dict[str, int] = field(default_factory=dict)
    cut: str | None = None
    shift_s: float = 0.0
    #: the image channel of a file another tool wrote (None: an ovis recording)
    channel: str | None = None
    #: messages that could not be published (an image that does not decode), and why
    skipped: int = 0
    skip_reason: str = ""


class Replayer:
    """Publishes a session's bus messages on ``session``."""

    def __init__(
        self,
        session: zenoh.Session,
        path: Path | str,
        *,
        speed: float | None = 1.0,
        loop: bool = False,
        only: list[str] | None = None,
        arena: str | None = None,
        stamps: str = "auto",
        stop: Stopping | None = None,
        on_frame: Callable[[int, int, str], None] | None = None,
        topic: str | None = None,
        on_skip: Callable[[str], None] | None = None,
    ) -> None:
        if stamps not in ("auto", "original", "now"):
            raise ValueError(f"stamps {stamps!r}: expected auto, original or now")
        for stage in only or []:
            if stage not in ONLY:
                raise ValueError(f"--only {stage!r}: choose among {', '.join(ONLY)}")
        self.session = session
        self.path = Path(path)
        self.speed = speed
        self.loop = loop
        self.suffixes = {s for stage in only or [] for s in ONLY[stage]} or None
        self.arena = arena
        self.stamps = stamps
        self.stop = stop or threading.Event()
        self.on_frame = on_frame
        self.on_skip = on_skip
        self.report = ReplayReport()
        self._pubs: dict[str, zenoh.Publisher] = {}
        self._last: dict[str, bytes] = {}  # the last payload published on each key
        # not a session, or no image channel to read: say so now
        channel = choose_channel(self.path, topic)
        self.foreign: ForeignFrames | None = None
        if channel is not None:
            if self.suffixes is not None and "frames" not in self.suffixes:
                raise ValueError(
                    f"{self.path} was written by another tool: it holds images only "
                    "(--only capture)"
                )
            key = Topics(arena or "default").frames
            self.foreign = ForeignFrames(self.path, channel, key, secrets.token_hex(8))
            self.report.channel = channel.describe()

    def _publisher(self, key: str) -> zenoh.Publisher:
        pub = self._pubs.get(key)
        if pub is None:
            pub = self._pubs[key] = self.session.declare_publisher(
                key,
                encoding=zenoh.Encoding(ENCODING),
                congestion_control=zenoh.CongestionControl.BLOCK,
            )
        return pub

    def _wanted(self, topic: str) -> bool:
        return self.suffixes is None or topic.rsplit("/", 1)[-1] in self.suffixes

    def run(self) -> ReplayReport:
        """Publish every pass (one, or until stopped with ``loop``); RecordingError if the
        file is damaged (what came before it has been published)."""
        pacer = Pacer(self.speed, time.monotonic, self.stop.wait)
        restamp = Restamp()
        r = self.report
        shifted = False
        while not self.stop.is_set():
            reader = SessionReader(self.path)
            sent_this_pass = 0
            start_ns: int | None = None
            pacer.restart()
            for log_ns, topic, make_payload in self._messages(reader):
                if not self._wanted(topic):
                    continue
                if not pacer.until(log_ns):
                    return r
                try:
                    payload = make_payload()
                except (ForeignError, MessageError) as exc:  # counted, said, skipped
                    r.skipped += 1
                    r.skip_reason = str(exc)
                    if self.on_skip is not None:
                        self.on_skip(r.skip_reason)
                    continue
                suffix = topic.rsplit("/", 1)[-1]
                if suffix == "frames":
                    if not shifted:
                        restamp.shift_ns = self._shift(payload)
                        r.shift_s, shifted = restamp.shift_ns / 1e9, True
                    payload = restamp.frame(payload)
                    if self.on_frame is not None and restamp.last is not None:
                        self.on_frame(*restamp.last, restamp.stream)
                    r.frames += 1
                elif suffix == "truth":
                    payload = restamp.truth(payload)
                key = rebase(topic, self.arena)
                start_ns = log_ns if start_ns is None else start_ns
                self._publisher(key).put(payload, attachment=self._mark(log_ns, start_ns))
                self._last[key] = payload
                r.messages += 1
                sent_this_pass += 1
                r.by_topic[key] = r.by_topic.get(key, 0) + 1
            r.cut = reader.cut
            r.passes += 1
            if not self.loop or sent_this_pass == 0:
                break
            restamp.next_pass()
        return r

    def _mark(self, recorded_ns: int, start_ns: int) -> bytes:
        """The attachment that says "replayed from this recording, logged then"."""
        mark = ReplayMark(recording=self.path.name, recorded_ns=recorded_ns, start_ns=start_ns)
        return msgspec.msgpack.encode(mark)

    def _messages(self, reader: SessionReader) -> Iterator[tuple[int, str, Callable[[], bytes]]]:
        """(log time, recorded key, the payload to publish) in file order."""
        if self.foreign is not None:
            yield from self.foreign.messages(reader)
            return
        for rec in reader.bus_messages():
            yield rec.log_ns, rec.topic, rec.payload

    def _shift(self, payload: bytes) -> int:
        """How far to move the stamps (``--stamps``), decided on the first frame."""
        if self.stamps == "original":
            return 0
        try:
            stamp = decode(payload, FrameHeader).stamp_ns
        except MessageError:
            return 0
        now = time.time_ns()
        if self.stamps == "now" or abs(now - stamp) / 1e9 > AUTO_RESTAMP_S:
            return now - stamp
        return 0

    def close(self, delivered: DeliveryCheck | None = None) -> bool:
        """Undeclare the publishers; with ``delivered``, first wait (at most ``FLUSH_S``)
        until the last message on each key has come back through the router. False if
        it did not come back in time."""
        arrived = delivered is None or delivered.wait(self._last, FLUSH_S)
        for pub in self._pubs.values():
            pub.undeclare()
        self._pubs.clear()
        return arrived


class DeliveryCheck:
    """A subscriber to ``ovis/**`` on a session of its own, declared before the replay's
    session opens: the replay waits until its last messages have come back through the
    router before its process ends. Closing a Zenoh session does not wait for the
    messages still queued to be sent, so a command that exits right after its last put
    loses them."""

    def __init__(self, session: zenoh.Session, key_expr: str = "ovis/**") -> None:
        self._lock = threading.Lock()
        self._latest: dict[str, zenoh.ZBytes] = {}
        self._sub = session.declare_subscriber(key_expr, self._keep)

    def _keep(self, sample: zenoh.Sample) -> None:
        with self._lock:
            self._latest[str(sample.key_expr)] = sample.payload

    def _arrived(self, last: dict[str, bytes]) -> bool:
        with self._lock:
            got = {k: self._latest.get(k) for k in last}
        return all(v is not None and v.to_bytes() == last[k] for k, v in got.items())

    def wait(self, last: dict[str, bytes], timeout: float) -> bool:
        """Whether every key's newest message is ``last``'s, within ``timeout``."""
        deadline = time.monotonic() + timeout
        while not self._arrived(last):
            if time.monotonic() > deadline:
                return False
            time.sleep(0.01)
        return True

    def close(self) -> None:
        self._sub.undeclare()


def capture_from_recording(service: Service, lost_for_good: Callable[[str], None]) -> None:
    """The capture stage with a session file as its source: the recorded frames (and
    ground truth) published bit-exact at the recorded pace, or the images of a file
    another tool wrote (its channel ``source_topic``, or its only image channel), looping
    if ``service.loop``; then it idles until stopped (a capture that exits would be
    restarted). An image that cannot be read is counted as a source error and skipped.
    A file that cannot be read, fails part way or is cut is the source lost for good
    (``lost_for_good`` with the reason: recorded, said, in the status); one read to its
    end is "recording ended"."""
    cfg = service.config.service

    def on_frame(seq: int, stamp_ns: int, stream: str) -> None:
        service.saw_frame(seq, stamp_ns, stream)
        service.sent()

    try:
        replayer = Replayer(
            service.session,
            cfg.source,
            speed=1.0,
            loop=cfg.loop,
            only=["capture"],
            arena=service.topics.arena,
            stop=service.stop,
            on_frame=on_frame,
            topic=cfg.source_topic or None,
            on_skip=lambda reason: service.error("source", reason),
        )
    except RecordingError as exc:
        lost_for_good(str(exc))
        service.ready()
        service.stop.wait()
        return
    service.ready()
    service.state = "ok"
    service.log.info("capturing from recording %s", cfg.source)
    failed = ""
    try:
        report = replayer.run()
    except RecordingError as exc:
        failed, report = str(exc), replayer.report
    if report.cut:
        service.log.warning("%s", report.cut)
    if report.shift_s:
        service.log.info("recorded stamps moved by %.0f s (the recording is old)", report.shift_s)
    if service.stop.is_set():  # stopped, not ended
        replayer.close()
        return
    why = failed or report.cut
    if why:
        lost_for_good(f"{cfg.source} ended early after {report.frames} frames: {why}")
    else:
        service.state = "recording ended"
        service.log.info("recording ended after %d frames", report.frames)
    service.stop.wait()
    replayer.close()
