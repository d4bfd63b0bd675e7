"""Replay behind ``ovis replay`` and ``ovis up --source SESSION.mcap``: the recorded bus
messages published again on their keys, at the recorded pace or as fast as Zenoh takes
them, frames rebuilt bit-exact (their recorded sequence numbers and stamps)."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import msgspec
import zenoh

from ovis.common.messages import ENCODING, FrameHeader, MessageError, ReplayMark, decode
from ovis.common.pipeline.stages import MAX_CLOCK_SKEW_S
from ovis.common.recording.pacing import Pacer, Restamp
from ovis.common.recording.session import RecordingError, SessionReader
from ovis.services.service import Service

__all__ = ["ONLY", "ReplayReport", "Replayer", "capture_from_recording", "is_recording"]

#: ``--only STAGE``: the topics each stage publishes.
ONLY: dict[str, tuple[str, ...]] = {
    "capture": ("frames", "truth"),
    "preprocess": ("binary",),
    "label": ("blobs",),
    "pose": ("obstacles", "health"),
    "calibrator": ("calibration",),
}
#: Stamps older than this are moved to now by ``--stamps auto`` (the preprocess service
#: refuses frames stamped more than MAX_CLOCK_SKEW_S away from its clock).
AUTO_RESTAMP_S = MAX_CLOCK_SKEW_S / 2


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
        stop: threading.Event | None = None,
        on_frame: Callable[[int, int], None] | None = None,
    ) -> None:
        if stamps not in ("auto", "original", "now"):
            raise ValueError(f"stamps {stamps!r}: expected auto, original or now")
        for stage in only or []:
            if stage not in ONLY:
                raise ValueError(f"--only {stage!r}: choose among {', '.join(ONLY)}")
        self.session = session
        self.path = Path(path)
        SessionReader(self.path)  # not a session: say so now
        self.speed = speed
        self.loop = loop
        self.suffixes = {s for stage in only or [] for s in ONLY[stage]} or None
        self.arena = arena
        self.stamps = stamps
        self.stop = stop or threading.Event()
        self.on_frame = on_frame
        self.report = ReplayReport()
        self._pubs: dict[str, zenoh.Publisher] = {}

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
            for rec in reader.bus_messages():
                if not self._wanted(rec.topic):
                    continue
                if not pacer.until(rec.log_ns):
                    return r
                payload = rec.payload()
                suffix = rec.topic.rsplit("/", 1)[-1]
                if suffix == "frames":
                    if not shifted:
                        restamp.shift_ns = self._shift(payload)
                        r.shift_s, shifted = restamp.shift_ns / 1e9, True
                    payload = restamp.frame(payload)
                    if self.on_frame is not None and restamp.last is not None:
                        self.on_frame(*restamp.last)
                    r.frames += 1
                elif suffix == "truth":
                    payload = restamp.truth(payload)
                key = rebase(rec.topic, self.arena)
                start_ns = rec.log_ns if start_ns is None else start_ns
                self._publisher(key).put(payload, attachment=self._mark(rec.log_ns, start_ns))
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

    def close(self) -> None:
        for pub in self._pubs.values():
            pub.undeclare()
        self._pubs.clear()


def capture_from_recording(service: Service) -> None:
    """The capture stage with a session file as its source: the recorded frames (and
    ground truth) published bit-exact at the recorded pace, looping if ``service.loop``;
    then it idles until stopped (a capture that exits would be restarted)."""
    cfg = service.config.service

    def on_frame(seq: int, stamp_ns: int) -> None:
        service.saw_frame(seq, stamp_ns)
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
        )
    except RecordingError as exc:
        service.state = "source unavailable"
        service.error("source", str(exc))
        service.ready()
        service.stop.wait()
        return
    service.ready()
    service.state = "ok"
    service.log.info("capturing from recording %s", cfg.source)
    try:
        report = replayer.run()
    except RecordingError as exc:
        service.error("source", str(exc))
        report = replayer.report
    if report.cut:
        service.log.warning("%s", report.cut)
    if report.shift_s:
        service.log.info("recorded stamps moved by %.0f s (the recording is old)", report.shift_s)
    service.state = "recording ended"
    service.log.info("recording ended after %d frames", report.frames)
    service.stop.wait()
    replayer.close()
