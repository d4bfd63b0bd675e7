"""One running stage and its loop: liveliness, the status queryable, counters, safe
decoding, the current calibration (followed as it is republished), and a clean
shutdown.

A service is a thin loop: take the newest message from an inbox, decode and validate it
(bad input is logged, counted and dropped — the service keeps running), call into
:mod:`ovis.common`, publish the result.
"""

from __future__ import annotations

import logging
import os
import signal
import threading
import time
from collections.abc import Callable
from typing import Any

import msgspec
import zenoh

from ovis.common.calibration.file import Calibration, calibration_from_config, wrong_arena
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
from ovis.common.pipeline.stages import wrong_size
from ovis.services.bus import open_session
from ovis.services.inbox import Inbox
from ovis.services.placement import pin_to_cpus

__all__ = ["Service", "run"]

log = logging.getLogger("ovis")


class Service:
    """One running stage: session, liveliness token, status queryable, counters."""

    def __init__(self, name: str, config: OvisConfig, session: zenoh.Session) -> None:
        self.name = name
        self.config = config
        self.session = session
        self.topics = Topics(config.service.arena)
        self.log = logging.getLogger(f"ovis.{name}")
        self.stop = threading.Event()
        self.started_ns = time.time_ns()
        self.state = "starting"
        self.counters = StageCounters()
        self.last_latency_ms: float | None = None
        self._inboxes: list[Inbox] = []
        self.calibration: Calibration = calibration_from_config(config)
        self._calibration_listeners: list[Callable[[Calibration], None]] = []
        self._token: zenoh.LivelinessToken | None = None  # declared by ready()
        self._status_q = session.declare_queryable(self.topics.status(name), self._on_status)

    # --- inputs -------------------------------------------------------------------
    def inbox(self, key: str, depth: int | None = None) -> Inbox:
        """Subscribe ``key`` into a newest-wins inbox of (payload bytes, receipt ns)."""
        box = Inbox(depth or self.config.service.queue_depth)
        self._inboxes.append(box)

        def on_sample(sample: zenoh.Sample) -> None:
            box.put((sample.payload.to_bytes(), time.time_ns()))

        self.session.declare_subscriber(key, on_sample)
        return box

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
        and log a ``bad_<kind>`` error."""
        return not self.refused(f"bad_{kind}", wrong_size(frame, self.calibration.camera, kind))

    def saw_frame(self, seq: int, stamp_ns: int) -> None:
        """Count an input frame; a gap in sequence numbers counts as dropped upstream."""
        self.counters.saw_frame(seq, stamp_ns)

    def sent(self) -> None:
        self.counters.sent()

    # --- outputs ------------------------------------------------------------------
    def publisher(self, key: str, *, drop: bool = True) -> Callable[[Any], None]:
        """A function that publishes a message (msgpack, ``application/msgpack``) on key."""
        pub = self.session.declare_publisher(
            key,
            encoding=zenoh.Encoding(ENCODING),
            congestion_control=(
                zenoh.CongestionControl.DROP if drop else zenoh.CongestionControl.BLOCK
            ),
        )
        return lambda message: pub.put(encode(message))

    def publish_result(self, publish: Callable[[Any], None], message: Any) -> None:
        """Publish one frame's result, count it, and say the stage works."""
        publish(message)
        self.sent()
        self.state = "ok"

    # --- calibration --------------------------------------------------------------
    def follow_calibration(self, on_change: Callable[[Calibration], None] | None = None) -> None:
        """Track the published calibration (fetch the current one, then every update)."""
        if on_change:
            self._calibration_listeners.append(on_change)

        def accept(payload: bytes) -> None:
            update = self.decode(payload, CalibrationUpdate, "calibration")
            if update is None:
                return
            calib = update.calibration
            if calib.version <= self.calibration.version:
                return
            if self.refused("bad_calibration", wrong_arena(calib, self.config)):
                return
            self.calibration = calib
            self.log.info("using calibration v%d (DIPE %.3f px)", calib.version, calib.dipe_px)
            for listener in self._calibration_listeners:
                listener(calib)

        self.session.declare_subscriber(
            self.topics.calibration, lambda s: accept(s.payload.to_bytes())
        )

        def fetch() -> None:
            # Until a calibration is known: a calibrator not reachable yet (starting, or a
            # peer still being discovered) answers nothing; one without a calibration
            # answers nothing until it has one (and then also publishes it).
            delay = 0.25
            while not self.stop.is_set() and self.calibration.version == 0:
                try:
                    for reply in self.session.get(self.topics.calibration, timeout=2.0):
                        if reply.ok is not None:
                            accept(reply.ok.payload.to_bytes())
                except zenoh.ZError:  # the session is closing
                    return
                self.stop.wait(delay)
                delay = min(2 * delay, 5.0)

        threading.Thread(target=fetch, name=f"{self.name}-calibration", daemon=True).start()

    # --- status -------------------------------------------------------------------
    def status(self) -> ServiceStatus:
        return self.counters.status(
            self.name,
            started_ns=self.started_ns,
            state=self.state,
            dropped_here=sum(b.dropped for b in self._inboxes),
            calibration_version=self.calibration.version,
        )

    def _on_status(self, query: zenoh.Query) -> None:
        try:
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
        has seen the subscribers declared before it."""
        if self._token is None:
            self._token = self.session.liveliness().declare_token(self.topics.alive(self.name))
            self.log.info("listening: alive on %s", self.topics.alive(self.name))

    def serve(self, inbox: Inbox, handle: Callable[[bytes, int], None]) -> None:
        """Run ``handle(payload, receipt_ns)`` on the newest input until stopped; an
        exception in ``handle`` is counted and logged, and the loop goes on.

        Zenoh's thread only drops each sample into the inbox and returns, so it is never
        blocked by the processing: when frames come faster than they can be processed,
        the older ones are dropped (counted) instead of queueing up in the network
        stack, and what is processed is always the newest."""
        self.state = "waiting for input"
        self.ready()
        while not self.stop.is_set():
            item = inbox.get(timeout=0.2)
            if item is None:
                continue
            try:
                handle(*item)
            except Exception as exc:
                self.error("processing", f"{type(exc).__name__}: {exc}")


def run(name: str, config: OvisConfig, main: Callable[[Service], None]) -> int:
    """Open a session, build the service, run ``main`` until SIGINT/SIGTERM, close."""
    logging.basicConfig(
        level=os.environ.get("OVIS_LOG", "INFO").upper(),
        format="%(asctime)s %(name)s %(levelname)s %(message)s",
    )
    pinned = pin_to_cpus(config.service.cpus, log)  # before Zenoh starts its threads
    with open_session(config.zenoh) as session:
        service = Service(name, config, session)

        def on_signal(signum: int, _frame: Any) -> None:
            service.log.info("signal %d: stopping", signum)
            service.stop.set()

        signal.signal(signal.SIGTERM, on_signal)
        signal.signal(signal.SIGINT, on_signal)
        service.log.info(
            "started (arena %s, pid %d, zenoh %s %s%s)",
            config.service.arena,
            os.getpid(),
            config.zenoh.mode,
            ",".join(config.zenoh.connect or config.zenoh.listen),
            f", cores {','.join(map(str, config.service.cpus))}" if pinned else "",
        )
        try:
            main(service)
        finally:
            service.stop.set()
            service.log.info("stopped: %s", msgspec.json.encode(service.status()).decode())
            exit_anyway_after(EXIT_GRACE_S, service.log)
    return 0


#: Seconds a stopped service may take to close its Zenoh session and exit.
EXIT_GRACE_S = 2.0


def exit_anyway_after(seconds: float, logger: logging.Logger) -> None:
    """Once a service has stopped (its state logged), make sure the process ends: a Zenoh
    session whose close, or an interpreter shutdown, hangs (seen on loaded hosts) would
    otherwise leave the supervisor to SIGKILL it and report an abnormal exit."""

    def force() -> None:
        logger.warning("closing took over %g s: exiting now", seconds)
        logging.shutdown()
        os._exit(0)

    timer = threading.Timer(seconds, force)
    timer.daemon = True
    timer.start()
