"""What every ovis service shares: its Zenoh session, liveliness, status, counters,
bounded inboxes, safe decoding, the current calibration, and a clean shutdown.

A service is a thin loop: take the newest message from an inbox, decode and validate it
(bad input is logged, counted and dropped — the service keeps running), call into
:mod:`ovis.common`, publish the result.
"""

from __future__ import annotations

import collections
import contextlib
import logging
import os
import resource
import signal
import socket
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import msgspec
import zenoh

from ovis.common.calibration.file import Calibration
from ovis.common.config import OvisConfig, ZenohConfig
from ovis.common.messages import (
    ENCODING,
    CalibrationUpdate,
    MessageError,
    ServiceStatus,
    Topics,
    decode,
    encode,
)

__all__ = [
    "Inbox",
    "Service",
    "ZenohUnreachableError",
    "calibration_from_config",
    "cpus_option",
    "local_peers",
    "open_session",
    "pick_cpus",
    "pin_to_cpus",
    "zenoh_config",
]

log = logging.getLogger("ovis")


def zenoh_config(zc: ZenohConfig, *, wait: bool = True) -> zenoh.Config:
    """A Zenoh configuration from ours: an optional JSON5 file, then mode/connect/listen.

    With ``wait``, a client keeps trying its routers instead of failing at once (a
    service started before its router waits for it); tools pass ``wait=False`` to say
    "no router" straight away.
    """
    if zc.config_file:
        path = Path(zc.config_file)
        if not path.is_file():
            raise FileNotFoundError(f"Zenoh configuration file {path} does not exist")
        conf = zenoh.Config.from_file(str(path))
    else:
        conf = zenoh.Config()
    conf.insert_json5("mode", msgspec.json.encode(zc.mode).decode())
    if zc.connect:
        conf.insert_json5("connect/endpoints", msgspec.json.encode(zc.connect).decode())
        if wait:
            conf.insert_json5("connect/timeout_ms", "-1")
            conf.insert_json5("connect/exit_on_failure", "false")
    if zc.listen:
        conf.insert_json5("listen/endpoints", msgspec.json.encode(zc.listen).decode())
    conf.insert_json5("scouting/multicast/enabled", "true" if zc.multicast_scouting else "false")
    return conf


#: Where services on the router's machine listen for each other (any free port).
LOOPBACK_PEER = "tcp/127.0.0.1:0"


def local_peers(zc: ZenohConfig) -> ZenohConfig:
    """The Zenoh settings for services that share the router's machine (``ovis up``):
    Zenoh peers listening on loopback instead of clients. They still join through the
    router, which tells them about each other (gossip), and then send each message
    straight to the next stage: one TCP hop per message instead of two through the
    router (four hops of this pipeline's message sizes at 30 frames/s, no work: p50
    ≈1.6–2.0 → ≈1.2–1.4 ms on this project's 2-core VM). Tools and
    subscribers on other machines still reach them through the router. A configuration
    with its own Zenoh file (TLS, access control) or mode is left as it is.
    """
    if zc.config_file or zc.mode != "client" or zc.listen:
        return zc
    return msgspec.structs.replace(zc, mode="peer", listen=[LOOPBACK_PEER])


#: The services every frame passes through, in order.
FRAME_PATH = ("capture", "preprocess", "label", "pose")


def pick_cpus(spec: str) -> list[int]:
    """Cores from ``--pin`` (``ovis up``: for the frame path, :data:`FRAME_PATH`) or
    ``--cpus`` (``ovis run``): "auto" (the last core this process may use, when it may
    use two or more: the others stay free for the router, the calibrator and
    subscribers), "none", or core numbers such as "1" or "0,2".

    Why one core: at camera rates every stage sleeps between frames and each hand-over
    wakes the next one; on the same core it finds numpy's and Zenoh's code still in
    cache and needs no cross-core wake-up. Measured at 640×480, 30 frames/s on this
    project's 2-core VM: end-to-end p50 2.84–3.89 ms in 11 runs on one core, 2.90–3.82
    ms in 8 runs on any core (minutes apart at a busy hour: 3.48, 4.01 on any core,
    3.04, 3.13 on one); one core sustains 300 frames/s at 640×480 and 200 at 1080p.
    """
    spec = spec.strip().lower()
    if spec == "none":
        return []
    allowed = sorted(os.sched_getaffinity(0))
    if spec == "auto":
        return allowed[-1:] if len(allowed) >= 2 else []
    try:
        cpus = sorted({int(part) for part in spec.split(",") if part.strip()})
    except ValueError:
        cpus = []
    if not cpus:
        raise ValueError(
            f"cores {spec!r}: expected 'auto', 'none' or core numbers such as 1 or 0,2"
        )
    missing = [c for c in cpus if c not in allowed]
    if missing:
        raise ValueError(
            f"cores {spec!r}: {missing} not available; this process may "
            f"use {','.join(map(str, allowed))}"
        )
    return cpus


def cpus_option(stage: str, cpus: list[int]) -> list[str]:
    """The ``ovis run STAGE`` arguments that put ``stage`` where ``ovis up`` puts it: on
    ``cpus`` if it is on the frame path (:data:`FRAME_PATH`; [] → "none"), else nothing."""
    if stage not in FRAME_PATH:
        return []
    return ["--cpus", ",".join(map(str, cpus)) or "none"]


def pin_to_cpus(cpus: list[int], log: logging.Logger) -> bool:
    """Restrict this process (and the threads it starts later) to ``cpus``; a core the
    machine does not have is logged and the process runs unpinned."""
    if not cpus:
        return False
    try:
        # Every thread, also those started at import (OpenBLAS's pool), which would not
        # inherit it; threads started later do.
        for tid in os.listdir("/proc/self/task"):
            with contextlib.suppress(ProcessLookupError):
                os.sched_setaffinity(int(tid), cpus)
    except (OSError, ValueError, AttributeError) as exc:
        log.warning(
            "cannot pin to cores %s (%s): running on any core; check [service] cpus",
            cpus,
            exc,
        )
        return False
    return True


class ZenohUnreachableError(RuntimeError):
    """No router answered at the configured endpoints."""


@contextmanager
def open_session(zc: ZenohConfig, *, wait: bool = True) -> Iterator[zenoh.Session]:
    """Open a Zenoh session and always close it (a session left open hangs the exit)."""
    try:
        session = zenoh.open(zenoh_config(zc, wait=wait))
    except zenoh.ZError as exc:
        raise ZenohUnreachableError(
            f"cannot reach Zenoh at {', '.join(zc.connect or zc.listen)}: {exc}. Is a router "
            "running there (`ovis router`, `ovis up`)? Use --connect to name another"
            + (
                f"; or did it refuse the TLS certificate or user/password of {zc.config_file}?"
                if zc.config_file
                else ""
            )
        ) from None
    try:
        yield session
    finally:
        session.close()


class Inbox:
    """A bounded queue where the newest item wins: when full, the oldest is dropped
    (and counted). Zenoh callbacks put; the service loop gets with a timeout."""

    def __init__(self, depth: int = 2) -> None:
        self._items: collections.deque[Any] = collections.deque(maxlen=depth)
        self._cond = threading.Condition()
        self.dropped = 0

    def put(self, item: Any) -> None:
        with self._cond:
            if len(self._items) == self._items.maxlen:
                self.dropped += 1
            self._items.append(item)
            self._cond.notify()

    def get(self, timeout: float) -> Any | None:
        with self._cond:
            if not self._items and timeout > 0:
                self._cond.wait(timeout)
            return self._items.popleft() if self._items else None

    def __len__(self) -> int:
        return len(self._items)


def _rss_mb() -> float:
    """Current resident set size (VmRSS), MB; the peak if /proc is unavailable."""
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def calibration_from_config(config: OvisConfig) -> Calibration:
    """Version 0: the configured (nominal, uncalibrated) camera and image settings."""
    return Calibration(
        version=0,
        dipe_px=0.0,
        dipe_mm=0.0,
        dipe_max_px=0.0,
        dipe_max_mm=0.0,
        camera=config.camera,
        image=config.image,
        pose=config.pose,
        source_image="configuration (not calibrated)",
    )


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
        self.frames_in = 0
        self.frames_out = 0
        self.errors: collections.Counter[str] = collections.Counter()
        self.last_error = ""
        self.last_frame_ns: int | None = None
        self.last_receipt_ns: int | None = None  # our clock, when the last frame came in
        self.last_latency_ms: float | None = None
        self._last_seq: int | None = None
        self._seq_gaps = 0
        self._inboxes: list[Inbox] = []
        self._rate: collections.deque[float] = collections.deque(maxlen=64)
        self._lock = threading.Lock()
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
        with self._lock:
            self.errors[kind] += 1
            n = self.errors[kind]
            self.last_error = message
        if n <= 5 or n % 100 == 0:
            self.log.warning("%s (%s #%d)", message, kind, n)

    def fits_camera(self, frame: Any, kind: str) -> bool:
        """True if ``frame`` (rows, cols, seq) has the calibrated camera's size; else count
        and log a ``bad_<kind>`` error."""
        cam = self.calibration.camera
        if (frame.rows, frame.cols) == (cam.rows, cam.cols):
            return True
        self.error(
            f"bad_{kind}",
            f"{kind} {frame.seq} is {frame.cols}x{frame.rows}, the camera is configured for "
            f"{cam.cols}x{cam.rows}",
        )
        return False

    def saw_frame(self, seq: int, stamp_ns: int) -> None:
        """Count an input frame; a gap in sequence numbers counts as dropped upstream."""
        with self._lock:
            self.frames_in += 1
            if self._last_seq is not None and seq > self._last_seq + 1:
                self._seq_gaps += seq - self._last_seq - 1
            if self._last_seq is None or seq > self._last_seq:
                self._last_seq = seq
            self.last_frame_ns = stamp_ns
            self.last_receipt_ns = time.time_ns()
            self._rate.append(time.monotonic())

    @property
    def last_seq(self) -> int | None:
        return self._last_seq

    def sent(self) -> None:
        with self._lock:
            self.frames_out += 1

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
            cam = calib.camera
            if (cam.rows, cam.cols) != (self.config.camera.rows, self.config.camera.cols):
                self.error(
                    "bad_calibration",
                    f"refused calibration v{calib.version}: it is for {cam.cols}x{cam.rows}, "
                    f"this arena is {self.config.camera.cols}x{self.config.camera.rows}",
                )
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
        now = time.monotonic()
        with self._lock:
            recent = [t for t in self._rate if now - t <= 5.0]
            fps = (len(recent) - 1) / (recent[-1] - recent[0]) if len(recent) > 1 else 0.0
            age = None
            if self.last_frame_ns is not None:
                age = (time.time_ns() - self.last_frame_ns) / 1e9
            dropped = self._seq_gaps + sum(b.dropped for b in self._inboxes)
            return ServiceStatus(
                service=self.name,
                pid=os.getpid(),
                host=socket.gethostname(),
                started_ns=self.started_ns,
                state=self.state,
                frames_in=self.frames_in,
                frames_out=self.frames_out,
                fps=round(fps, 2),
                dropped=dropped,
                errors=dict(self.errors),
                last_error=self.last_error,
                calibration_version=self.calibration.version,
                last_frame_age_s=age,
                rss_mb=_rss_mb(),
                restarts=int(os.environ.get("OVIS_RESTARTS", "0") or 0),
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
    return 0
