"""Supervision of the router and the stages started by `ovis up`.

A child that dies is restarted after a back-off while its restart budget lasts (the
rule: :mod:`ovis.common.pipeline.restarts`); the reason (exit code or signal, and the
last lines of its log) is logged. Children get SIGTERM when the supervisor dies
(``PR_SET_PDEATHSIG``), so nothing is left orphaned, and the number of restarts is
passed to each child (``OVIS_RESTARTS``) so that `ovis status` shows it.
"""

from __future__ import annotations

import contextlib
import ctypes
import logging
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from ovis.common.messages import ServiceStatus
from ovis.common.pipeline.restarts import RestartBudget, describe_exit
from ovis.common.pipeline.totals import CounterTotals, ServiceTotals
from ovis.services.placement import ALLOWED_ENV

__all__ = ["STANDBY", "Child", "Supervisor", "die_with_parent"]

log = logging.getLogger("ovis.up")

#: A spare is started this long after its stage (not while everything starts at once).
SPARE_AFTER_S = 5.0
#: Stages of the frame path that `ovis up` keeps a spare process ready for: a killed one
#: is replaced without an interpreter start (the cost: one idle process each).
STANDBY = ("preprocess", "label", "pose")
#: On stopping, how long the stages get after the cameras stop for the frames in flight.
DRAIN_S = 0.3
#: Children that write a file on stopping (the recorder: its backlog, then the file's
#: summary and index), stopped after the stages (their last messages recorded) and given
#: this long before SIGKILL, which would leave a recording without its index.
WRITERS_STOP_S = {"recorder": 60.0}


def die_with_parent() -> None:
    """In the child: get SIGTERM when the launching process dies (no orphans)."""
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG


def _in_child(cpus: list[int]) -> None:
    """In the child, before it runs: no orphans, its own process group, and on ``cpus``
    if any are given. In a group of its own, a Ctrl-C in the terminal reaches only the
    launcher, which stops the children in order (the capture first, what it captured
    still processed) after asking their last counts: a child stopping by itself at the
    same moment left the summary counting more frames processed than captured."""
    die_with_parent()
    os.setpgrp()
    if cpus:
        with contextlib.suppress(OSError):
            os.sched_setaffinity(0, cpus)


@dataclass
class Child:
    """One supervised process."""

    name: str
    args: list[str]
    budget: RestartBudget
    proc: subprocess.Popen[bytes] | None = None
    started_at: float = 0.0
    restart_at: float | None = None
    gave_up: str = ""
    last_exit: str = ""
    standby: bool = False  # keep a spare process ready (imports done) to take over
    spare: subprocess.Popen[bytes] | None = None
    #: cores a spare does its imports on, off the frame path ([]: any); once activated,
    #: it moves to its stage's own cores (``--cpus``, pinned by the service)
    spare_cpus: list[int] = field(default_factory=list)


class Supervisor:
    """Starts, watches, restarts and stops `ovis` child processes."""

    def __init__(self, log_dir: Path, *, max_restarts: int = 5, window_s: float = 60.0) -> None:
        self.log_dir = log_dir
        self.max_restarts = max_restarts
        self.window_s = window_s
        self.children: dict[str, Child] = {}
        self.events: list[str] = []
        self.stopping = False
        self.counters = CounterTotals()  # every status seen, summed over restarts
        self._streams: dict[str, set[str]] = {}  # capture stream identities, by child
        self._host = socket.gethostname()

    def start(
        self, name: str, args: list[str], *, standby: bool = False, spare_cpus: Sequence[int] = ()
    ) -> None:
        """Start child ``name``; with ``standby``, also a spare that has done its imports
        and waits (:func:`ovis.services.service.wait_for_activation`) to replace it at
        once if it dies: its first restart then costs no interpreter start. The spare
        starts on ``spare_cpus`` (if given) so that its imports do not take the running
        frame path's core."""
        if name not in self.children:
            budget = RestartBudget(self.max_restarts, self.window_s)
            self.children[name] = Child(
                name, args, budget, standby=standby, spare_cpus=list(spare_cpus)
            )
        child = self.children[name]
        child.started_at = time.monotonic()
        child.proc = self._spawn(child)

    def _spawn(self, child: Child, *, spare: bool = False) -> subprocess.Popen[bytes]:
        logfile = open(self.log_dir / f"{child.name}.log", "ab")  # noqa: SIM115 (the child keeps it)
        env = dict(os.environ, OVIS_RESTARTS=str(child.budget.restarts))
        if spare and child.spare_cpus:  # started off the frame path, pinned to it later
            env[ALLOWED_ENV] = ",".join(map(str, sorted(os.sched_getaffinity(0))))
        args = child.args
        if spare:  # `ovis run --standby STAGE …`
            args = [args[0], "--standby", *args[1:]]
        cores = child.spare_cpus if spare else []
        proc = subprocess.Popen(
            [sys.executable, "-m", "ovis.services.cli", *args],
            stdout=logfile,
            stderr=subprocess.STDOUT,
            stdin=subprocess.PIPE if spare else subprocess.DEVNULL,
            preexec_fn=lambda: _in_child(cores),
            env=env,
        )
        logfile.close()
        return proc

    def _restart(self, child: Child) -> None:
        """Activate the spare (the restart count on its stdin), or spawn a process."""
        spare, child.spare = child.spare, None
        if spare is not None and spare.poll() is None and spare.stdin is not None:
            try:
                spare.stdin.write(f"{child.budget.restarts}\n".encode())
                spare.stdin.close()
                child.proc = spare
            except OSError:
                spare = None
        if child.proc is not spare:
            child.proc = self._spawn(child)

    def _tail(self, name: str, lines: int = 3) -> str:
        try:
            text = (self.log_dir / f"{name}.log").read_text(errors="replace")
        except OSError:
            return ""
        return " | ".join(ln.strip() for ln in text.strip().splitlines()[-lines:])

    def supervise(self) -> list[str]:
        """Restart children that died (once their back-off has passed); return what
        happened since the last call. A child out of budget is left stopped."""
        now = time.monotonic()
        news: list[str] = []
        for child in self.children.values():
            if self.stopping or child.gave_up or child.proc is None:
                continue
            if child.restart_at is not None:  # dead, waiting for its back-off
                if now >= child.restart_at:
                    child.budget.restarted(now)
                    child.restart_at = None
                    child.started_at = now
                    self._restart(child)
                    news.append(f"{child.name} restarted (restart {child.budget.restarts})")
                continue
            code = child.proc.poll()
            if code is None:
                child.budget.running(now, child.started_at)
                if child.standby and child.spare is None and now - child.started_at > SPARE_AFTER_S:
                    child.spare = self._spawn(child, spare=True)
                continue
            child.last_exit = describe_exit(code)
            backoff = child.budget.died(now)
            if backoff is None:
                child.gave_up = (
                    f"{child.name} died ({child.last_exit}) and used its restart budget "
                    f"({self.max_restarts} in {self.window_s:g} s): left stopped"
                )
                news.append(child.gave_up)
                log.error(child.gave_up)
                continue
            child.restart_at = now + backoff
            msg = (
                f"{child.name} died ({child.last_exit}); restarting in {backoff:g} s. "
                f"Last log: {self._tail(child.name)}"
            )
            news.append(msg)
            log.warning(msg)
        self.events.extend(news)
        return news

    def gave_up(self) -> list[str]:
        return [c.gave_up for c in self.children.values() if c.gave_up]

    def failures(self, codes: dict[str, int]) -> list[str]:
        """Why the run failed, given the children's exit ``codes`` (:meth:`stop`): those
        that used their restart budget, and every other that exited abnormally."""
        bad = [
            f"{name} ({describe_exit(code)})"
            for name, code in codes.items()
            if code not in (0, -signal.SIGTERM) and not self.children[name].gave_up
        ]
        return self.gave_up() + [f"process(es) {', '.join(bad)} exited abnormally"] * bool(bad)

    def owns(self, status: ServiceStatus) -> bool:
        """Whether ``status`` is one of this supervisor's own processes (its pid on this
        host): another system's services on the same bus are not counted."""
        child = self.children.get(status.service)
        proc = child.proc if child is not None else None
        return proc is not None and status.pid == proc.pid and status.host == self._host

    def record(self, statuses: dict[str, ServiceStatus]) -> None:
        """Keep the children's latest statuses: their counters survive restarts; and
        the stream identities they report (the capture's: this run's frames)."""
        for status in statuses.values():
            self.counters.record(status)
            if status.stream or status.frames_in:  # "": frames with no stream identity
                self._streams.setdefault(status.service, set()).add(status.stream)

    def streams(self, name: str) -> set[str]:
        """The stream identities child ``name`` reported (each start makes a new one)."""
        return set(self._streams.get(name, ()))

    def totals(self) -> dict[str, ServiceTotals]:
        """Each child's counters over all of its processes."""
        return self.counters.totals()

    def pids(self) -> dict[str, int]:
        """The running processes by name (a spare as ``<name> spare``)."""
        running = {}
        for name, child in self.children.items():
            for label, proc in ((name, child.proc), (f"{name} spare", child.spare)):
                if proc is not None and proc.poll() is None:
                    running[label] = proc.pid
        return running

    def restarts(self) -> dict[str, int]:
        return {n: c.budget.restarts for n, c in self.children.items()}

    def stop(self, timeout: float = 5.0, *, sources: Sequence[str] = ()) -> dict[str, int]:
        """SIGTERM the ``sources`` (the cameras) and wait for them, give what they sent
        :data:`DRAIN_S` to reach the stages (a recording then holds every frame
        captured), then SIGTERM the other stages, then the writers
        (:data:`WRITERS_STOP_S`), then the router; SIGKILL whatever outlives ``timeout``
        (a writer: its own time)."""
        self.stopping = True
        codes: dict[str, int] = {}
        for child in self.children.values():
            if child.spare is not None and child.spare.poll() is None:
                child.spare.kill()  # only waiting: nothing to stop cleanly
                child.spare.wait()
        first = [n for n in self.children if n in sources]
        last = ("router", *WRITERS_STOP_S)
        stages = [n for n in self.children if n not in last and n not in sources]
        codes |= self._stop_group(first, timeout)
        if first:
            time.sleep(DRAIN_S)
        codes |= self._stop_group(stages, timeout)
        for name, writer_s in WRITERS_STOP_S.items():
            if name in self.children:
                codes |= self._stop_group([name], writer_s)
        if "router" in self.children:
            codes |= self._stop_group(["router"], timeout)
        return codes

    def _stop_group(self, names: list[str], timeout: float) -> dict[str, int]:
        """SIGTERM ``names`` at once and wait for them (SIGKILL after ``timeout``)."""
        codes: dict[str, int] = {}
        for name in names:
            p = self.children[name].proc
            if p is not None and p.poll() is None:
                p.send_signal(signal.SIGTERM)
        deadline = time.monotonic() + timeout
        for name in names:
            p = self.children[name].proc
            if p is None:
                continue
            try:
                codes[name] = p.wait(max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                p.kill()
                codes[name] = p.wait()
        return codes
