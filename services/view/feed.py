"""The view's side of the bus: what it knows of each arena, kept up to date by Zenoh
callbacks (liveliness, obstacles, stream health, calibration, the robots' commands and
drive reports; frames, binary frames and blobs only while a browser watches the
arena), and the recalibration query.

Callbacks only validate and store the newest items (bounded), never encode or draw:
that is done by the server at the browser's rate. A message that fails validation is
counted and dropped, and so is an obstacle or health message without the pose stage's
proof of origin, or a calibration without the calibrator's (:mod:`ovis.common.trust`;
the health panel counts them), but for a replay: its recording kept no proofs, and the
page says it is one. Each item is kept with when it arrived and its replay mark (the
attachment ``ovis replay`` puts on what it publishes), so that the page can say how
current it is and whether it is a replay.
"""

from __future__ import annotations

import collections
import contextlib
import logging
import threading
import time
from typing import Annotated, Any

import msgspec
import zenoh

from ovis.common.calibration.file import Calibration
from ovis.common.config import OvisConfig
from ovis.common.messages import (
    CalibrateReply,
    CalibrateRequest,
    CalibrationUpdate,
    MessageError,
    ObstacleFrame,
    ReplayMark,
    RobotCommand,
    RobotDrive,
    ServiceStatus,
    StreamHealth,
    Topics,
    decode,
    encode,
)
from ovis.common.pipeline.following import newer
from ovis.common.pipeline.limits import Input, oversized
from ovis.common.pipeline.totals import claimed_once
from ovis.common.view.driving import Drives, RobotShown, robot_poses
from ovis.common.view.freshness import (
    Freshness,
    Seen,
    freshness,
    read_replay_mark,
    replay_of_result,
)
from ovis.common.view.health import HealthSummary, LatencyWindow, summarize
from ovis.common.view.scene import camera_footprint
from ovis.services.memory import GUARD
from ovis.services.trust import attachment_of, every_reply, unproven, verifier_for

__all__ = ["ArenaFeed", "Bus", "Item"]

log = logging.getLogger("ovis.view")

#: Seconds a service whose liveliness token went away shows as down, even if a
#: replacement (``ovis up``'s spare) took over sooner: a person sees that it died.
DIED_HOLD_S = 2.0

#: Recent messages kept per arena to pair a frame with its detections.
KEEP = 8


#: A kept frame, binarised frame or blob list: its payload and when it arrived.
Item = tuple[bytes, Seen]


class _Head(msgspec.Struct):
    """The sequence number and capture stamp of any frame-like message (the rest is
    skipped)."""

    seq: Annotated[int, msgspec.Meta(ge=0)]
    stamp_ns: Annotated[int, msgspec.Meta(ge=0)]


def _newest(store: collections.OrderedDict[int, Any], seq: int, item: Any) -> None:
    store[seq] = item
    store.move_to_end(seq)
    while len(store) > KEEP:
        store.popitem(last=False)


class ArenaFeed:
    """One arena as the view sees it."""

    def __init__(self, session: zenoh.Session, arena: str, config: OvisConfig) -> None:
        self.session = session
        self.pose = verifier_for(config, "pose")
        self.calibrator = verifier_for(config, "calibrator")
        self.planner = verifier_for(config, "planner")
        self.topics = Topics(arena)
        self.arena = arena
        self.lock = threading.Lock()
        self.alive: set[str] = set()
        #: when each service's liveliness token last went away (monotonic s): a stage
        #: that died and was replaced at once still shows as down for DIED_HOLD_S
        self.died: dict[str, float] = {}
        self.statuses: dict[str, ServiceStatus] = {}
        self.latency = LatencyWindow()
        self.stream: StreamHealth | None = None
        self.stream_received_s = 0.0
        #: the newest camera frame, binarised frame and obstacle message received
        self.seen: dict[str, Seen] = {}
        #: since when the view looks for frames (a browser watches), and for obstacles
        self.looking_since_s: float | None = None
        self.started_s = time.monotonic()
        self.calibration: Calibration | None = None
        self.footprint: list[tuple[float, float]] = []
        self.obstacles: collections.OrderedDict[int, dict[str, Any]] = collections.OrderedDict()
        self.obstacle_messages = 0
        #: the robots' newest commands and recent drive reports (issue 37, item 7)
        self.drives = Drives(config.navigation)
        self.drive_messages = 0
        self.frames: collections.OrderedDict[int, Item] = collections.OrderedDict()
        self.binaries: collections.OrderedDict[int, Item] = collections.OrderedDict()
        self.blobs: collections.OrderedDict[int, Item] = collections.OrderedDict()
        self.refused: collections.Counter[str] = collections.Counter()
        #: messages dropped for lack of their signer's proof, by kind
        self.unproven: collections.Counter[str] = collections.Counter()
        self.frames_seen = 0
        self._watchers = 0
        self._frame_subs: list[zenoh.Subscriber] = []
        t = self.topics
        self._subs = [
            session.declare_subscriber(t.obstacles, self._on_obstacles),
            session.declare_subscriber(t.health, self._on_health),
            session.declare_subscriber(t.calibration, self._on_calibration),
            session.declare_subscriber(t.commands_all, self._on_command),
            session.declare_subscriber(t.drives_all, self._on_drive),
            session.liveliness().declare_subscriber(t.alive_all, self._on_alive, history=True),
        ]

    # --- callbacks (Zenoh threads) --------------------------------------------------
    def refuse(self, what: str, exc: MessageError) -> None:
        with self.lock:
            self.refused[what] += 1
            n = self.refused[what]
        if n <= 3 or n % 100 == 0:
            log.warning("arena %s: refused a %s message: %s (#%d)", self.arena, what, exc, n)

    def proven(self, sample: zenoh.Sample, payload: bytes, what: str) -> bool:
        """Whether an obstacle or health message has the pose stage's proof; one without
        is dropped and counted, unless it is a replay (kept: the page labels it)."""
        problem = unproven(self.pose, sample, payload)
        if problem is None or self._mark(sample) is not None:
            return True
        self.refuse_unproven(what, problem)
        return False

    def refuse_unproven(self, what: str, problem: str) -> None:
        with self.lock:
            self.unproven[what] += 1
        self.refuse(f"unproven {what}", MessageError(problem))

    def take(self, payload: zenoh.ZBytes, kind: Input, what: str) -> bytes | None:
        """The bytes of a payload, or None (counted, never copied) when it is larger than
        a message of ``kind`` may be with the arena's camera (none known yet: the hard
        cap), see :mod:`ovis.common.pipeline.limits`."""
        camera = None if self.calibration is None else self.calibration.camera
        problem = oversized(len(payload), kind, what, camera)
        if problem is not None:
            self.refuse(what, MessageError(problem))
            GUARD.request()  # give back what Zenoh took to receive it
            return None
        return payload.to_bytes()

    def _on_alive(self, sample: zenoh.Sample) -> None:
        name = str(sample.key_expr).rsplit("/", 1)[-1]
        with self.lock:
            if sample.kind == zenoh.SampleKind.PUT:
                self.alive.add(name)
            else:
                self.alive.discard(name)
                self.statuses.pop(name, None)
                self.died[name] = time.monotonic()

    def _mark(self, sample: zenoh.Sample) -> ReplayMark | None:
        """The sample's replay mark; a bad one is counted and the sample taken as live."""
        attachment = sample.attachment
        try:
            return read_replay_mark(None if attachment is None else attachment.to_bytes())
        except ValueError as exc:
            self.refuse("replay mark", MessageError(str(exc)))
            return None

    def _seen(self, sample: zenoh.Sample, seq: int, stamp_ns: int) -> Seen:
        return Seen(
            seq=seq,
            stamp_ns=stamp_ns,
            received_ns=time.time_ns(),
            received_s=time.monotonic(),
            replay=self._mark(sample),
        )

    def _on_obstacles(self, sample: zenoh.Sample) -> None:
        payload = self.take(sample.payload, "blobs", "obstacles")
        if payload is None or not self.proven(sample, payload, "obstacles"):
            return
        try:
            msg = decode(payload, ObstacleFrame)  # validates; the page gets every field
        except MessageError as exc:
            self.refuse("obstacles", exc)
            return
        generic = msgspec.msgpack.decode(payload)
        seen = self._seen(sample, msg.seq, msg.stamp_ns)
        with self.lock:
            if seen.replay is None:
                kept = self.frames.get(msg.seq)
                replay = replay_of_result(
                    None if kept is None else kept[1],
                    self.seen.get("camera"),
                    msg.stamp_ns,
                    seen.received_s,
                )
                seen = msgspec.structs.replace(seen, replay=replay)
            _newest(self.obstacles, msg.seq, generic)
            self.obstacle_messages += 1
            self.seen["obstacles"] = seen
            if seen.replay is None:  # a replay's stamps are not now's: no latency
                self.latency.add((seen.received_ns - msg.stamp_ns) / 1e6)

    def _robot_message(self, sample: zenoh.Sample, tp: Any) -> tuple[Any, ReplayMark | None]:
        """A robot's command (``tp`` RobotCommand: only with the planner's proof, or
        replayed) or drive report, validated, and its replay mark; None (counted) when
        refused."""
        what = "cmd" if tp is RobotCommand else "drive"
        payload = self.take(sample.payload, "small", what)
        if payload is None:
            return None, None
        replay = self._mark(sample)
        if tp is RobotCommand and replay is None:
            problem = unproven(self.planner, sample, payload)
            if problem is not None:
                self.refuse_unproven(what, problem)
                return None, None
        try:
            return decode(payload, tp), replay
        except MessageError as exc:
            self.refuse(what, exc)
            return None, None

    def _on_command(self, sample: zenoh.Sample) -> None:
        msg, replay = self._robot_message(sample, RobotCommand)
        if msg is not None:
            with self.lock:
                self.drives.command(msg, time.monotonic(), replay)
                self.drive_messages += 1

    def _on_drive(self, sample: zenoh.Sample) -> None:
        msg, _replay = self._robot_message(sample, RobotDrive)
        if msg is not None:
            with self.lock:
                self.drives.drive(msg)
                self.drive_messages += 1

    def robots_shown(self) -> tuple[int, list[RobotShown]]:
        """How many commands and drive reports arrived, and each driven robot as the map
        draws it now (:mod:`ovis.common.view.driving`)."""
        with self.lock:
            kept = list(self.obstacles.items())
            frames = {int(m.get("stamp_ns", -1)): seq for seq, m in kept}
            poses = {seq: robot_poses(m) for seq, m in kept}
            shown = self.drives.shown(time.time_ns(), time.monotonic(), frames, poses)
            return self.drive_messages, shown

    def _on_health(self, sample: zenoh.Sample) -> None:
        payload = self.take(sample.payload, "small", "health")
        if payload is None or not self.proven(sample, payload, "health"):
            return
        try:
            msg = decode(payload, StreamHealth)
        except MessageError as exc:
            self.refuse("health", exc)
            return
        with self.lock:
            self.stream = msg
            self.stream_received_s = time.monotonic()

    def _on_calibration(self, sample: zenoh.Sample) -> None:
        replay = self._mark(sample) is not None  # a recording's: kept no proof, and says so
        self.accept_calibration(sample.payload, attachment_of(sample), replay=replay)

    def accept_calibration(
        self, received: zenoh.ZBytes, proof: bytes | None, *, replay: bool = False
    ) -> None:
        """A calibration with the calibrator's proof (or replayed), newer than the one
        shown."""
        payload = self.take(received, "small", "calibration")
        if payload is None:
            return
        problem = self.calibrator.problem(self.topics.calibration, payload, proof)
        if problem is not None and not replay:
            self.refuse_unproven("calibration", problem)
            return
        try:
            calib = decode(payload, CalibrationUpdate).calibration
            footprint = camera_footprint(calib.camera)
        except (MessageError, ValueError) as exc:
            self.refuse("calibration", MessageError(str(exc)))
            return
        with self.lock:
            if self.calibration is None or newer(calib, self.calibration):
                self.calibration = calib
                self.footprint = footprint

    def _keeper(self, store: collections.OrderedDict[int, Item], what: Input, kind: str | None):
        def on_sample(sample: zenoh.Sample) -> None:
            payload = self.take(sample.payload, what, what)
            if payload is None:
                return
            try:  # only the sequence number and stamp now; the rest when a picture is made
                head = msgspec.msgpack.decode(payload, type=_Head)
            except (msgspec.DecodeError, msgspec.ValidationError) as exc:
                self.refuse(what, MessageError(str(exc)))
                return
            seen = self._seen(sample, head.seq, head.stamp_ns)
            with self.lock:
                _newest(store, head.seq, (payload, seen))
                if kind is not None:
                    self.seen[kind] = seen
                if what == "frame":
                    self.frames_seen += 1

        return on_sample

    # --- watching: frames flow to this process only while a browser looks -----------
    def watch(self) -> None:
        with self.lock:
            self._watchers += 1
            if self._watchers > 1:
                return
            t = self.topics
            self.looking_since_s = time.monotonic()
            self._frame_subs = [
                self.session.declare_subscriber(
                    t.frames, self._keeper(self.frames, "frame", "camera")
                ),
                self.session.declare_subscriber(
                    t.binary, self._keeper(self.binaries, "binary", "binary")
                ),
                self.session.declare_subscriber(t.blobs, self._keeper(self.blobs, "blobs", None)),
            ]

    def unwatch(self) -> None:
        with self.lock:
            self._watchers = max(0, self._watchers - 1)
            if self._watchers:
                return
            subs, self._frame_subs = self._frame_subs, []
            self.frames.clear()
            self.binaries.clear()
            self.blobs.clear()
            self.seen.pop("camera", None)
            self.seen.pop("binary", None)
            self.looking_since_s = None
        for sub in subs:
            sub.undeclare()

    # --- polling (the bus thread) -----------------------------------------------------
    def poll(self, timeout: float) -> None:
        """Ask every service of the arena for its status (every answer: a second one in
        a service's name makes it "degraded" at least, :func:`claimed_once`), and the
        calibrator for the calibration while none is known."""
        statuses: dict[str, ServiceStatus] = {}
        for reply in every_reply(self.session, self.topics.status_all, timeout=timeout):
            if reply.ok is None:
                continue
            payload = self.take(reply.ok.payload, "small", "status")
            if payload is None:
                continue
            try:
                st = decode(payload, ServiceStatus)
            except MessageError as exc:
                self.refuse("status", exc)
                continue
            seen = statuses.get(st.service)  # two answers in one name: the worse, said
            statuses[st.service] = st if seen is None else claimed_once(seen, st)
        with self.lock:
            self.statuses = {n: s for n, s in statuses.items() if n in self.alive}
            need_calibration = self.calibration is None
        if need_calibration:
            for reply in every_reply(self.session, self.topics.calibration, timeout=timeout):
                if reply.ok is not None:
                    self.accept_calibration(reply.ok.payload, attachment_of(reply.ok))

    def freshness(self, kind: str) -> Freshness:
        """How current the newest item of ``kind`` (camera, binary, obstacles) is now."""
        with self.lock:
            since = self.started_s if kind == "obstacles" else self.looking_since_s
            return freshness(
                self.seen.get(kind), time.time_ns(), time.monotonic(), looking_since_s=since
            )

    def health(self) -> HealthSummary:
        fresh = {kind: self.freshness(kind) for kind in ("camera", "binary", "obstacles")}
        now = time.monotonic()
        with self.lock:
            shown = {n for n in self.alive if now - self.died.get(n, -DIED_HOLD_S) >= DIED_HOLD_S}
            return summarize(
                self.arena,
                shown,
                self.statuses,
                self.latency,
                self.stream,
                self.calibration,
                stream_age_s=now - self.stream_received_s if self.stream is not None else None,
                fresh=fresh,
                unproven=self.unproven,
            )

    def recalibrate(self, request: CalibrateRequest, timeout: float) -> CalibrateReply:
        """Send the recalibration query (as `ovis recalibrate` does) and wait for the
        calibrator's reply; failures come back as a reply with ``ok`` False."""
        replies = list(
            self.session.get(self.topics.calibrate, payload=encode(request), timeout=timeout)
        )
        if not replies:
            return CalibrateReply(
                ok=False,
                error=f"no calibrator answered on {self.topics.calibrate} within {timeout:g} s",
            )
        reply = replies[0]
        if reply.ok is None:
            why = reply.err.payload.to_bytes().decode(errors="replace")
            return CalibrateReply(ok=False, error=f"the calibrator failed: {why}")
        try:
            return decode(reply.ok.payload.to_bytes(), CalibrateReply)
        except MessageError as exc:
            return CalibrateReply(ok=False, error=f"the calibrator's reply is not valid: {exc}")

    def close(self) -> None:
        for sub in [*self._subs, *self._frame_subs]:
            with contextlib.suppress(zenoh.ZError):
                sub.undeclare()


class Bus:
    """The view's Zenoh session: the arenas it follows (named, or found by liveliness
    when none is named) and a thread that polls their status every ``period_s``."""

    def __init__(
        self,
        session: zenoh.Session,
        arenas: list[str],
        *,
        discover: bool,
        config: OvisConfig,
        period_s: float = 1.0,
    ) -> None:
        self.session = session
        self.config = config  # whose public keys the feeds trust
        self.period_s = period_s
        self.lock = threading.Lock()
        self.feeds: dict[str, ArenaFeed] = {}
        self.found: set[str] = set()  # arenas seen alive, followed from the next poll
        self.stop = threading.Event()
        for arena in arenas:
            self.feed(arena)
        self._discover = None
        if discover:
            self._discover = session.liveliness().declare_subscriber(
                "ovis/*/alive/*", self._on_any_alive, history=True
            )
        self._thread = threading.Thread(target=self._poll, name="view-poll", daemon=True)
        self._thread.start()

    def _on_any_alive(self, sample: zenoh.Sample) -> None:
        parts = str(sample.key_expr).split("/")
        if sample.kind == zenoh.SampleKind.PUT and len(parts) == 4:
            with self.lock:
                self.found.add(parts[1])

    def feed(self, arena: str) -> ArenaFeed:
        """The feed of ``arena`` (started on first use; ValueError for a bad name)."""
        with self.lock:
            feed = self.feeds.get(arena)
            if feed is None:
                feed = self.feeds[arena] = ArenaFeed(self.session, arena, self.config)
                log.info("following arena %s", arena)
            return feed

    def arenas(self) -> list[str]:
        with self.lock:
            return sorted(self.feeds)

    def _poll(self) -> None:
        while not self.stop.is_set():
            t0 = time.monotonic()
            with self.lock:
                found, self.found = self.found - set(self.feeds), set()
            for arena in found:
                try:
                    self.feed(arena)
                except ValueError:
                    log.warning("ignored an arena with an invalid name: %r", arena)
            with self.lock:
                feeds = list(self.feeds.values())
            for feed in feeds:
                try:
                    feed.poll(timeout=min(1.0, self.period_s))
                except zenoh.ZError:
                    if self.stop.is_set():
                        return
            self.stop.wait(max(0.05, self.period_s - (time.monotonic() - t0)))

    def close(self) -> None:
        self.stop.set()
        self._thread.join(timeout=3.0)
        if self._discover is not None:
            self._discover.undeclare()
        with self.lock:
            feeds = list(self.feeds.values())
        for feed in feeds:
            feed.close()
