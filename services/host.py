"""One stage process serving several cameras (``[service] layout = "per-stage"``).

Each camera gets its own :class:`~ovis.services.service.Service` on the process's one
Zenoh session (its topics, counters, status, liveliness and calibration: what its own
process would have), and its stage's ``main`` runs in a thread of its own (a capture
reads each source in its own thread). The frame handlers of all the cameras run on one
thread, :class:`SharedLoop`, which takes the cameras' newest inputs in turn: one
wake-up serves the frames the cameras took together, with the stage's code and data
still in cache, instead of one process per camera each waking cold.

Isolation: a frame that fails is counted for its camera only (as in its own process); a
camera whose handler does not come back within :data:`STUCK_S` is left to it, and the
other cameras go on in a new thread (the stuck camera rejoins once its handler
returns); a camera whose ``main`` fails says so in its status while the others run on.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import msgspec

from ovis.common.messages import ServiceStatus
from ovis.services.inbox import Inbox

if TYPE_CHECKING:
    from ovis.services.service import Service

__all__ = ["STUCK_S", "SharedLoop", "serve_cameras"]

#: A handler busy this long with one input is stuck: the other cameras go on without it.
STUCK_S = 1.0
#: How often the loop looks at its inboxes when nothing wakes it (and the stop is seen).
IDLE_S = 0.2


@dataclass
class _Entry:
    """One camera's input and its handler."""

    service: Service
    inbox: Inbox
    handle: Callable[[bytes, int], None]
    stuck: bool = False


class _Worker:
    """A thread of the shared loop; superseded (``current`` False) when it got stuck."""

    def __init__(self) -> None:
        self.current = True
        #: the entry being handled and since when (monotonic s), or None
        self.busy: tuple[_Entry, float] | None = None


class SharedLoop:
    """Serves the inboxes of several cameras' services on one thread, in turn: each pass
    takes at most one input of each camera, so a camera with a flood of input cannot
    starve the others, and each inbox keeps only its newest inputs (dropped ones are
    counted by the camera's status, as before)."""

    def __init__(self, stuck_s: float = STUCK_S) -> None:
        self.stuck_s = stuck_s
        self.wake = threading.Event()
        self._entries: list[_Entry] = []
        self._lock = threading.Lock()
        self._worker: _Worker | None = None
        self._stopped = threading.Event()

    def add(self, service: Service, inbox: Inbox, handle: Callable[[bytes, int], None]) -> None:
        """Serve ``inbox`` with ``handle`` from now on (``service`` counts the outcomes)."""
        inbox.wake = self.wake
        with self._lock:
            self._entries = [*self._entries, _Entry(service, inbox, handle)]
        self.wake.set()

    def start(self) -> None:
        """Start serving (a thread)."""
        self._spawn()

    def stop(self) -> None:
        self._stopped.set()
        self.wake.set()

    def _spawn(self) -> None:
        worker = _Worker()
        self._worker = worker
        threading.Thread(target=self._serve, args=(worker,), name="cameras", daemon=True).start()

    def _serve(self, worker: _Worker) -> None:
        while worker.current and not self._stopped.is_set():
            self.wake.wait(IDLE_S)
            self.wake.clear()
            while self._pass(worker):
                pass

    def _pass(self, worker: _Worker) -> bool:
        """One input of each camera that has one; False when there was none (or this
        worker is superseded)."""
        served = False
        for entry in self._entries:
            if not worker.current or self._stopped.is_set():
                return False
            if entry.stuck or entry.service.stop.is_set():
                continue
            item = entry.inbox.get(timeout=0)
            if item is None:
                continue
            worker.busy = (entry, time.monotonic())
            entry.service.handle_one(item, entry.handle)
            worker.busy = None
            served = True
            if entry.stuck:  # it came back: it rejoins the current worker's turns
                entry.stuck = False
                entry.service.log.warning("its handler came back: served again")
                self.wake.set()
        return served

    def watch(self, now: float | None = None) -> str | None:
        """Called now and then from another thread: when the worker has been busy with
        one camera's input for longer than ``stuck_s``, leave that camera to it and go
        on with the others in a new thread; the camera's name, or None."""
        worker = self._worker
        busy = worker.busy if worker is not None else None
        if worker is None or busy is None:
            return None
        entry, since = busy
        now = time.monotonic() if now is None else now
        if now - since <= self.stuck_s or entry.stuck:
            return None
        entry.stuck = True
        service = entry.service
        service.state = f"stuck: an input's handler busy for over {self.stuck_s:g} s"
        service.error(
            "stuck",
            f"an input's handler has been busy for {now - since:.1f} s: this camera waits "
            "for it, the process's other cameras go on",
        )
        worker.current = False
        self._spawn()
        return service.topics.camera


def _failed(service: Service, why: str) -> Callable[[ServiceStatus], ServiceStatus]:
    """What the status of a camera whose stage stopped on an error says."""
    amend = service.amend_status

    def status(st: ServiceStatus) -> ServiceStatus:
        st = st if amend is None else amend(st)
        return msgspec.structs.replace(st, state="failing", reason=why)

    return status


def _camera_main(main: Callable[[Service], None], service: Service) -> None:
    """One camera's ``main`` in its thread: an error stops that camera only, and its
    status says why (the process and the other cameras run on)."""
    try:
        main(service)
    except Exception as exc:
        why = f"stage stopped: {type(exc).__name__}: {exc}"
        service.log.exception("%s", why)
        service.error("stage", why)
        service.amend_status = _failed(service, why)


def serve_cameras(services: Sequence[Service], main: Callable[[Service], None]) -> None:
    """Run ``main`` for each camera's service in a thread of its own, their frame
    handlers on one :class:`SharedLoop`, until any of them is stopped (the process's
    signal stops them all)."""
    loop = SharedLoop()
    for service in services:
        service.shared = loop
        service.log = logging.getLogger(f"ovis.{service.name}.{service.topics.camera}")
    loop.start()
    threads = [
        threading.Thread(
            target=_camera_main,
            args=(main, service),
            name=f"{service.name}-{service.topics.camera}",
            daemon=True,
        )
        for service in services
    ]
    for thread in threads:
        thread.start()
    first = services[0].stop
    try:
        while not first.wait(IDLE_S / 2):
            loop.watch()
    finally:
        for service in services:
            service.stop.set()
        loop.stop()
        deadline = time.monotonic() + 1.0
        for thread in threads:
            thread.join(max(0.0, deadline - time.monotonic()))
