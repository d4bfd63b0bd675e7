"""One running stage and its loop: liveliness, the status queryable, counters, safe
decoding, the current calibration (followed as it is republished), and a clean
shutdown.

A service is a thin loop: take the newest message from an inbox, decode and validate it
(bad input is logged, counted and dropped — the service keeps running), call into
:mod:`ovis.common`, publish the result.
"""

from __future__ import annotations

import gc
import logging
import os
import signal
import sys
import threading
import time
import traceback
from collections.abc import Callable, Sequence
from typing import Any

import msgspec
import zenoh

from ovis.common.calibration.file import Calibration, calibration_from_config
from ovis.common.config import OvisConfig
from ovis.common.messages import (
    ENCODING,
    CalibrationUpdate,
    MessageError,
    ServiceStatus,
    Topics,
    decode,
    encode,
)
from ovis.common.pipeline.counters import StageCounters, worth_logging
from ovis.common.pipeline.following import (
    RECONCILE_S,
    Answer,
    CalibrationFollower,
    label,
    pick,
)
from ovis.common.pipeline.hosting import camera_config
from ovis.common.pipeline.limits import Input, PayloadLimits, oversized
from ovis.common.pipeline.stages import wrong_size
from ovis.common.trust.proof import Signer
from ovis.services.bus import open_session
from ovis.services.host import SharedLoop, serve_cameras
from ovis.services.inbox import Inbox
from ovis.services.memory import GUARD, keep_freed_memory
from ovis.services.placement import pin_to_cpus
from ovis.services.shm import ShmWriter
from ovis.services.stopping import Stop
from ovis.services.trust import attachment_of, every_reply, unproven, verifier_for

__all__ = ["Service", "run"]

log = logging.getLogger("ovis")

#: Largest messages the shared memory of a service holds at once.
SHM_FRAMES = 6


class Service:
    """One running stage: session, liveliness token, status queryable, counters."""

    def __init__(self, name: str, config: OvisConfig, session: zenoh.Session) -> None:
        self.name = name
        self.config = config
        self.session = session
        self.topics = Topics(config.service.arena, config.service.camera_name)
        self.log = logging.getLogger(f"ovis.{name}")
        self.stop = Stop()  # set by the signal handler (see ovis.services.stopping)
        self.started_ns = time.time_ns()
        self.state = "starting"
        self.counters = StageCounters()
        self.last_latency_ms: float | None = None
        self._inboxes: list[Inbox] = []
        self.calibration: Calibration = calibration_from_config(config)
        self._calibration_listeners: list[Callable[[Calibration], None]] = []
        self.follower: CalibrationFollower | None = None  # set by follow_calibration()
        self._token: zenoh.LivelinessToken | None = None  # declared by ready()
        #: what a stage adds to its status (the capture: its source's losses)
        self.amend_status: Callable[[ServiceStatus], ServiceStatus] | None = None
        #: what SIGUSR1 toggles in this stage, if anything (a capture: its camera
        #: unplugged); the process's handler calls it for each of its cameras
        self.on_user_signal: Callable[[], None] | None = None
        #: the shared memory that large messages are written into (:meth:`publisher`)
        self.shm: ShmWriter | None = None
        self._shm_lock = threading.Lock()  # publishers are declared from several threads
        #: the one loop that serves every camera of this process (services/host.py), or
        #: None: :meth:`serve` runs its own
        self.shared: SharedLoop | None = None
        self._status_q = session.declare_queryable(self.topics.status(name), self._on_status)

    # --- inputs -------------------------------------------------------------------
    def inbox(self, key: str, depth: int | None = None, proven_by: str | None = None) -> Inbox:
        """Subscribe ``key`` into a newest-wins inbox of (payload bytes, receipt ns); a
        payload larger than its kind may be (:meth:`take`) is refused unread, and with
        ``proven_by`` (a role: "pose") one without that role's proof of origin is dropped
        and counted (:meth:`proven`)."""
        box = Inbox(depth or self.config.service.queue_depth)
        self._inboxes.append(box)
        kinds: dict[str, Input] = {
            self.topics.frames: "frame",
            self.topics.binary: "binary",
            self.topics.blobs: "blobs",
        }
        kind = kinds.get(key, "small")
        what = key.rsplit("/", 1)[-1] if kind == "small" else kind  # as bad_<what> is named

        proven = self.proven(proven_by, what) if proven_by else None

        def on_sample(sample: zenoh.Sample) -> None:
            payload = self.take(sample.payload, kind, what)
            if payload is not None and (proven is None or proven(sample, payload)):
                box.put((payload, time.time_ns()))

        self.session.declare_subscriber(key, on_sample)
        return box

    def proven(self, role: str, what: str) -> Callable[[zenoh.Sample, bytes], bool]:
        """A check that a received sample carries ``role``'s proof of origin; one that
        does not is counted (``unproven_<what>``), said, and must be dropped."""
        verifier = verifier_for(self.config, role)

        def check(sample: zenoh.Sample, payload: bytes) -> bool:
            if (problem := unproven(verifier, sample, payload)) is None:
                return True
            said = f"dropped {what} without a current proof from the {role}: {problem}"
            self.error(f"unproven_{what}", said)
            return False

        return check

    def fits(self, payload: zenoh.ZBytes | None, kind: Input, what: str) -> bool:
        """False when a received payload is larger than a message of ``kind`` may be
        with this camera (:mod:`ovis.common.pipeline.limits`): it is counted
        (``oversized_<what>``) and logged, and the memory Zenoh took to receive it is
        given back shortly after (:data:`~ovis.services.memory.GUARD`)."""
        size = 0 if payload is None else len(payload)
        problem = oversized(size, kind, what, self.calibration.camera)
        if self.refused(f"oversized_{what}", problem):
            GUARD.request()
        return problem is None

    def take(self, payload: zenoh.ZBytes | None, kind: Input, what: str) -> bytes | None:
        """The bytes of a received payload (none: empty), or None when it does not
        :meth:`fit <fits>` (it is then never copied)."""
        if not self.fits(payload, kind, what):
            return None
        return b"" if payload is None else payload.to_bytes()

    def receive(
        self, payload: zenoh.ZBytes | None, kind: Input, expected: Any, what: str
    ) -> Any | None:
        """A received payload :meth:`taken <take>` and :meth:`decoded <decode>`, or None
        (refused, counted and logged)."""
        data = self.take(payload, kind, what)
        return None if data is None else self.decode(data, expected, what)

    def decode(self, payload: bytes, expected: Any, what: str) -> Any | None:
        """Decode a payload, or count and log why not (``bad_<what>``) and return None."""
        try:
            return decode(payload, expected)
        except MessageError as exc:
            self.error(f"bad_{what}", f"refused a {len(payload)}-byte {what} message: {exc}")
            return None

    def error(self, kind: str, message: str) -> None:
        """Count an error of ``kind`` and log it (the first 5 of a kind, then every 100th)."""
        n = self.counters.error(kind, message)
        if worth_logging(n):
            self.log.warning("%s (%s #%d)", message, kind, n)

    def refused(self, kind: str, problem: str | None) -> bool:
        """True (and the problem counted as ``kind`` and logged) when there is one."""
        if problem is None:
            return False
        self.error(kind, problem)
        return True

    @property
    def last_error(self) -> str:
        return self.counters.last_error

    def fits_camera(self, frame: Any, kind: str) -> bool:
        """True if ``frame`` (rows, cols, seq) has the calibrated camera's size; else count
        and log a ``bad_<kind>`` error. A real camera's frame needs a calibration: the
        configured camera (version 0) is the simulator's, not a real camera's."""
        if self.refused(f"bad_{kind}", wrong_size(frame, self.calibration.camera, kind)):
            return False
        return not self.refused("no_calibration", self._uncalibrated(frame.seq, kind))

    def _uncalibrated(self, seq: int, kind: str) -> str | None:
        """Why a real camera's frame cannot be processed yet (no calibration), or None."""
        if self.calibration.version > 0 or self.config.starts_with_configured_camera:
            return None
        refused = self.follower.problem() if self.follower is not None else None
        return f"{kind} {seq} not processed: no calibration for this camera" + (
            f" ({refused})" if refused else " (waiting for the calibrator's)"
        )

    def await_calibration(self) -> None:
        """For a real camera's frames, return once the calibrator's calibration is in use
        (or on stop): a stage says it listens only then, so no frame is refused for the
        lack of one at start, and nothing is made for the configured camera (version 0:
        the simulator's)."""
        if self.follower is None or self.config.starts_with_configured_camera:
            return
        self.state = "waiting for the calibration"
        while self.calibration.version == 0 and not self.stop.wait(0.05):
            pass

    def saw_frame(self, seq: int, stamp_ns: int, stream: str = "") -> None:
        """Count an input frame of the capture's ``stream``; a plausible gap in sequence
        numbers counts as dropped upstream (:meth:`StageCounters.saw_frame`)."""
        self.counters.saw_frame(seq, stamp_ns, stream)

    def sent(self) -> None:
        self.counters.sent()

    # --- outputs ------------------------------------------------------------------
    def publisher(
        self, key: str, *, drop: bool = True, signer: Signer | None = None
    ) -> Callable[[Any], None]:
        """A function that publishes a message (msgpack, ``application/msgpack``) on key,
        with ``signer``'s proof of origin in the attachment if given; written into the
        shared-memory pool when ``[zenoh] shared_memory`` is on (large messages only)."""
        pub = self.session.declare_publisher(
            key,
            encoding=zenoh.Encoding(ENCODING),
            congestion_control=(
                zenoh.CongestionControl.DROP if drop else zenoh.CongestionControl.BLOCK
            ),
        )
        wrap = self._shared_memory()
        if signer is None:
            return lambda message: pub.put(wrap(encode(message)))

        def put(message: Any) -> None:
            payload = encode(message)
            pub.put(wrap(payload), attachment=signer.attachment(key, payload))

        return put

    def _shared_memory(self) -> Callable[[bytes], Any]:
        """What a payload is put as: the bytes, or their copy in the service's one
        shared-memory pool (:class:`~ovis.services.shm.ShmWriter`)."""
        if not self.config.zenoh.shared_memory:
            return lambda payload: payload
        with self._shm_lock:  # one pool for all the service's publishers, whichever thread
            if self.shm is None:
                pool = SHM_FRAMES * max(PayloadLimits.of(self.config.camera))
                self.shm = ShmWriter(pool, self.log)
            return self.shm.payload

    def publish_result(self, publish: Callable[[Any], None], message: Any) -> None:
        """Publish one frame's result, count it, and say the stage works."""
        publish(message)
        self.sent()
        self.state = "ok"

    # --- calibration --------------------------------------------------------------
    def follow_calibration(self, on_change: Callable[[Calibration], None] | None = None) -> None:
        """Use the calibrator's current calibration (:mod:`ovis.common.pipeline.following`):
        ask its queryable now, every ``RECONCILE_S``, and whenever a calibration with the
        calibrator's proof is pushed on the topic (the push itself is never taken: a
        recorded genuine one can be pushed again)."""
        if on_change:
            self._calibration_listeners.append(on_change)
        self.follower = CalibrationFollower(self.config, self.calibration)
        self._calibrator = verifier_for(self.config, "calibrator")
        ask = threading.Event()

        def on_push(sample: zenoh.Sample) -> None:
            payload = self.take(sample.payload, "small", "calibration")
            if payload is None:
                return
            if problem := unproven(self._calibrator, sample, payload):
                self._conflict(f"a push on {sample.key_expr}: refused, {problem}")
            elif self.decode(payload, CalibrationUpdate, "calibration"):
                ask.set()

        self.session.declare_subscriber(self.topics.calibration, on_push)

        def reconcile() -> None:
            delay = 0.25  # quick retries until the calibrator first answers
            while not self.stop.is_set():
                ask.clear()
                try:
                    answered = self.reconcile_calibration()
                except zenoh.ZError:  # the session is closing
                    return
                if answered:
                    delay = RECONCILE_S
                ask.wait(delay)
                delay = min(2 * delay, RECONCILE_S)

        threading.Thread(target=reconcile, name=f"{self.name}-calibration", daemon=True).start()

    def _conflict(self, text: str) -> None:
        """Count a calibration conflict (``calibration_conflict``); the status says it."""
        self.error("calibration_conflict", text)
        if self.follower is not None:
            self.follower.conflict(text, time.monotonic())

    def reconcile_calibration(self, timeout: float = 2.0) -> bool:
        """Ask every queryable of the calibration for its answer and use the calibrator's
        proven one if it is newer than ours and valid; unproven answers and replays are
        counted as conflicts (:func:`~ovis.common.pipeline.following.pick`). False when
        nobody answered with the calibrator's proof."""
        answers = []
        for reply in every_reply(self.session, self.topics.calibration, timeout=timeout):
            if reply.ok is None:
                continue
            who = f"replier {reply.replier_id.zid}" if reply.replier_id else "a replier"
            payload = self.take(reply.ok.payload, "small", "calibration")
            if payload is None:
                continue
            proof = attachment_of(reply.ok)
            problem = self._calibrator.problem(self.topics.calibration, payload, proof)
            update = self.decode(payload, CalibrationUpdate, "calibration")
            if update is not None:
                answers.append(Answer(who, update.calibration, problem))
        calib, conflicts = pick(self.calibration, answers)
        for text in conflicts:
            self._conflict(text)
        if calib is not None:
            adopted, problem = self.follower.offer(calib)
            if problem is not None:
                self.error("bad_calibration", problem)
            if adopted:
                self._use(calib, f"using calibration {label(calib)} (DIPE {calib.dipe_px:.3f} px)")
        return any(a.unproven is None for a in answers)

    def _use(self, calib: Calibration, message: str) -> None:
        self.calibration = calib
        self.log.info("%s", message)
        for listener in self._calibration_listeners:
            listener(calib)

    def _frame_failed(self, calib: Calibration, error: str) -> None:
        """Roll back, at once, a calibration that made this stage fail on a frame."""
        if self.follower is None:
            return
        back = self.follower.failed(calib, error)
        if back is not None:
            message = (
                f"calibration {label(calib)} failed on a frame ({error}): rolled back to "
                f"{label(back)}"
            )
            self.error("calibration_rollback", message)
            self._use(back, message)

    # --- status -------------------------------------------------------------------
    def status(self) -> ServiceStatus:
        status = self.counters.status(
            self.name,
            started_ns=self.started_ns,
            state=self.state,
            dropped_here=sum(b.dropped for b in self._inboxes),
            calibration_version=self.calibration.version,
            calibration_epoch=self.calibration.epoch,
            problem=self.follower.problem() if self.follower is not None else None,
        )
        if self.shm is not None:  # its shared memory: what went in, what went as bytes
            status = msgspec.structs.replace(
                status,
                shm_pool_bytes=self.shm.pool_bytes,
                shm_written=self.shm.written,
                shm_fallbacks=self.shm.fallbacks,
            )
        return status if self.amend_status is None else self.amend_status(status)

    def _on_status(self, query: zenoh.Query) -> None:
        try:
            self.fits(query.payload, "small", "status_query")  # none is expected
            query.reply(
                self.topics.status(self.name),
                encode(self.status()),
                encoding=zenoh.Encoding(ENCODING),
            )
        except Exception as exc:  # never let a status query kill the service
            self.log.warning("status reply failed: %s", exc)

    # --- main loop ----------------------------------------------------------------
    def ready(self) -> None:
        """Declare the liveliness token ``ovis/<arena>/alive/<name>``: call it once the
        stage listens to its inputs, so that whoever waits for it to be alive (``ovis
        up`` before it starts the capture, tests before they publish) loses nothing.
        Zenoh sends a session's declarations in order, so a peer that sees the token
        has seen the subscribers declared before it.

        What the start made (modules, tables, the session) is moved out of the garbage
        collector's sight first (``gc.freeze``): a full collection would otherwise walk
        all of it now and then, a pause in the middle of a frame."""
        if self._token is None:
            gc.collect()
            gc.freeze()
            self._token = self.session.liveliness().declare_token(self.topics.alive(self.name))
            self.log.info("listening: alive on %s", self.topics.alive(self.name))

    def serve(self, inbox: Inbox, handle: Callable[[bytes, int], None]) -> None:
        """Run ``handle(payload, receipt_ns)`` on the newest input until stopped; an
        exception in ``handle`` is counted and logged, and the loop goes on.

        Zenoh's thread only drops each sample into the inbox and returns, so it is never
        blocked by the processing: when frames come faster than they can be processed,
        the older ones are dropped (counted) instead of queueing up in the network
        stack, and what is processed is always the newest."""
        self.await_calibration()
        if self.stop.is_set():  # stopped before a calibration came: its session is closed
            return
        self.state = "waiting for input"
        self.ready()
        if self.shared is not None:  # one loop serves every camera of the process
            self.shared.add(self, inbox, handle)
            self.stop.wait()
            return
        while not self.stop.is_set():
            item = inbox.get(timeout=0.2)
            if item is not None:
                self.handle_one(item, handle)

    def handle_one(self, item: tuple[bytes, int], handle: Callable[[bytes, int], None]) -> None:
        """Run ``handle`` on one input: an exception is counted and logged, and a
        calibration that made it fail is rolled back; the outcome is counted."""
        calib, sent = self.calibration, self.counters.frames_out
        try:
            handle(*item)
        except Exception as exc:
            error = f"{type(exc).__name__}: {exc}"
            self.error("processing", error)
            self.counters.outcome(False)
            self._frame_failed(calib, error)
            return
        worked = self.counters.frames_out > sent
        self.counters.outcome(worked)
        if worked and self.follower is not None:
            self.follower.worked(calib)


def wait_for_activation() -> bool:
    """A spare started by the supervisor (``OVIS_STANDBY=1``) waits here, its imports
    done, until the supervisor writes the restart count on its stdin (it then takes
    over from a stage that died); False when the supervisor closes stdin first."""
    if os.environ.get("OVIS_STANDBY") != "1":
        return True
    line = sys.stdin.readline().strip()
    if not line.isdigit():
        return False
    os.environ["OVIS_RESTARTS"] = line
    os.environ.pop("OVIS_STANDBY")
    return True


def run(
    name: str,
    config: OvisConfig,
    main: Callable[[Service], None],
    cameras: Sequence[str] = (),
    warm: Callable[[OvisConfig], None] | None = None,
) -> int:
    """Open a session, build the service, run ``main`` until SIGINT/SIGTERM, close.

    With ``cameras`` (names of ``[[cameras]]``), the process serves each of them, on its
    own topics with its own status (:func:`~ovis.services.host.serve_cameras`); one
    camera is that camera's chain, as with ``[service] camera_name``. A spare process
    runs ``warm`` on each camera's configuration before it waits to take over (what its
    stage makes at start and can make ahead: its first frames then come sooner)."""
    configs = [camera_config(config, camera) for camera in cameras] or [config]
    if warm is not None and os.environ.get("OVIS_STANDBY") == "1":
        for each in configs:
            warm(each)
    if not wait_for_activation():
        return 0
    logging.basicConfig(
        level=os.environ.get("OVIS_LOG", "INFO").upper(),
        format="%(asctime)s %(name)s %(levelname)s %(message)s",
    )
    pinned = pin_to_cpus(config.service.cpus, log)  # before Zenoh starts its threads
    keep_freed_memory(max(max(PayloadLimits.of(c.camera)) for c in configs))  # … and allocates
    with open_session(config.zenoh) as session:
        services = [Service(name, c, session) for c in configs]
        service = services[0]

        def on_signal(signum: int, _frame: Any) -> None:
            service.log.info("signal %d: stopping", signum)
            if not service.stop.is_set():
                exit_if_stuck_after(STOP_GRACE_S, service.log)
            for each in services:
                each.stop.set()

        def on_user_signal(_signum: int, _frame: Any) -> None:
            toggles = [each.on_user_signal for each in services if each.on_user_signal]
            if not toggles:
                service.log.warning("SIGUSR1 ignored: this stage has nothing it toggles")
            for toggle in toggles:
                toggle()

        signal.signal(signal.SIGTERM, on_signal)
        signal.signal(signal.SIGINT, on_signal)
        # set here, in the main thread: a stage's main may run in a thread of its own
        # (several cameras), where it cannot set a handler, and SIGUSR1's default ends
        # the process
        signal.signal(signal.SIGUSR1, on_user_signal)
        service.log.info(
            "started (arena %s, pid %d, zenoh %s %s%s%s)",
            config.service.arena,
            os.getpid(),
            config.zenoh.mode,
            ",".join(config.zenoh.connect or config.zenoh.listen),
            f", cores {','.join(map(str, config.service.cpus))}" if pinned else "",
            f", cameras {','.join(cameras)}" if cameras else "",
        )
        try:
            if len(services) > 1:
                serve_cameras(services, main)
            else:
                main(service)
        finally:
            for each in services:
                each.stop.set()
                each.log.info("stopped: %s", msgspec.json.encode(each.status()).decode())
            exit_anyway_after(EXIT_GRACE_S, service.log)
    # The session is closed: end here rather than in the interpreter's shutdown, where
    # Zenoh's threads (shared memory's among them) still inside its native code can
    # abort the process ("FATAL: exception not rethrown", SIGABRT) after a clean stop.
    logging.shutdown()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(0)


#: Seconds a stopped service may take to close its Zenoh session and exit.
EXIT_GRACE_S = 2.0
#: Seconds from a stop signal to the exit, whatever the service is doing (less than the
#: supervisor waits before it kills).
STOP_GRACE_S = 3.5


def exit_if_stuck_after(seconds: float, logger: logging.Logger) -> None:
    """After a stop signal, make sure the process ends within ``seconds``: a stage whose
    loop does not come back (blocked in a call that the closing network never answers)
    would otherwise be killed by the supervisor and counted as an abnormal exit. Where
    each thread was is logged, to find out why."""

    def stacks() -> str:
        return "".join(
            f"\n  thread {ident}:\n" + "".join(traceback.format_stack(frame)[-4:])
            for ident, frame in sys._current_frames().items()
        )

    _exit_after(
        seconds,
        lambda: logger.warning(
            "not stopped %g s after the signal: exiting now; stacks:%s", seconds, stacks()
        ),
    )


def exit_anyway_after(seconds: float, logger: logging.Logger) -> None:
    """Once a service has stopped (its state logged), make sure the process ends: a Zenoh
    session whose close, or an interpreter shutdown, hangs (seen on loaded hosts) would
    otherwise leave the supervisor to SIGKILL it and report an abnormal exit."""
    _exit_after(seconds, lambda: logger.warning("closing took over %g s: exiting now", seconds))


def _exit_after(seconds: float, say: Callable[[], None]) -> None:
    """In ``seconds``, unless the process has ended: ``say`` why, then exit (code 0)."""

    def force() -> None:
        say()
        logging.shutdown()
        os._exit(0)

    timer = threading.Timer(seconds, force)
    timer.daemon = True
    timer.start()
