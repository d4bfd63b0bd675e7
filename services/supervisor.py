"""Supervision of the router and the stages started by `ovis up`.

A child that dies is restarted after a back-off (1 s, doubling up to 10 s) while its
restart budget lasts (``max_restarts`` within ``window_s``); the reason (exit code or
signal, and the last lines of its log) is logged. Children get SIGTERM when the
supervisor dies (``PR_SET_PDEATHSIG``), so nothing is left orphaned, and the number of
restarts is passed to each child (``OVIS_RESTARTS``) so that `ovis status` shows it.
"""

from __future__ import annotations

import contextlib
import ctypes
import logging
import os
import signal
import subprocess
import sys
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path

__all__ = ["Child", "Supervisor", "describe_exit", "die_with_parent"]

log = logging.getLogger("ovis.up")

BACKOFF_START_S = 1.0
BACKOFF_MAX_S = 10.0


def die_with_parent() -> None:
    """In the child: get SIGTERM when the launching process dies (no orphans)."""
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG


def describe_exit(code: int) -> str:
    """'exit code 3' or 'killed by SIGKILL'."""
    if code < 0:
        try:
            return f"killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exit code {code}"


@dataclass
class Child:
    """One supervised process."""

    name: str
    args: list[str]
    proc: subprocess.Popen[bytes] | None = None
    restarts: int = 0
    recent: deque[float] = field(default_factory=lambda: deque(maxlen=64))
    started_at: float = 0.0
    restart_at: float | None = None
    backoff: float = BACKOFF_START_S
    gave_up: str = ""
    last_exit: str = ""


class Supervisor:
    """Starts, watches, restarts and stops `ovis` child processes."""

    def __init__(self, log_dir: Path, *, max_restarts: int = 5, window_s: float = 60.0) -> None:
        self.log_dir = log_dir
        self.max_restarts = max_restarts
        self.window_s = window_s
        self.children: dict[str, Child] = {}
        self.events: list[str] = []
        self.stopping = False

    def start(self, name: str, args: list[str]) -> None:
        child = self.children.setdefault(name, Child(name, args))
        child.started_at = time.monotonic()
        self._spawn(child)

    def _spawn(self, child: Child) -> None:
        logfile = open(self.log_dir / f"{child.name}.log", "ab")  # noqa: SIM115 (the child keeps it)
        env = dict(os.environ, OVIS_RESTARTS=str(child.restarts))
        child.proc = subprocess.Popen(
            [sys.executable, "-m", "ovis.services.cli", *child.args],
            stdout=logfile,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            preexec_fn=die_with_parent,
            env=env,
        )
        logfile.close()

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
                    child.restarts += 1
                    child.recent.append(now)
                    child.restart_at = None
                    child.started_at = now
                    self._spawn(child)
                    news.append(f"{child.name} restarted (restart {child.restarts})")
                continue
            code = child.proc.poll()
            if code is None:
                if now - child.started_at > 30.0:  # has run fine for a while
                    child.backoff = BACKOFF_START_S
                continue
            child.last_exit = describe_exit(code)
            while child.recent and now - child.recent[0] > self.window_s:
                child.recent.popleft()
            if len(child.recent) >= self.max_restarts:
                child.gave_up = (
                    f"{child.name} died ({child.last_exit}) and used its restart budget "
                    f"({self.max_restarts} in {self.window_s:g} s): left stopped"
                )
                news.append(child.gave_up)
                log.error(child.gave_up)
                continue
            child.restart_at = now + child.backoff
            msg = (
                f"{child.name} died ({child.last_exit}); restarting in {child.backoff:g} s. "
                f"Last log: {self._tail(child.name)}"
            )
            news.append(msg)
            log.warning(msg)
            child.backoff = min(BACKOFF_MAX_S, child.backoff * 2)
        self.events.extend(news)
        return news

    def gave_up(self) -> list[str]:
        return [c.gave_up for c in self.children.values() if c.gave_up]

    def restarts(self) -> dict[str, int]:
        return {n: c.restarts for n, c in self.children.items()}

    def stop(self, timeout: float = 5.0) -> dict[str, int]:
        """SIGTERM the stages, then the router; SIGKILL whatever outlives ``timeout``."""
        self.stopping = True
        codes: dict[str, int] = {}
        stages = [n for n in self.children if n != "router"]
        for group in (stages, [n for n in self.children if n == "router"]):
            for name in group:
                p = self.children[name].proc
                if p is not None and p.poll() is None:
                    p.send_signal(signal.SIGTERM)
            deadline = time.monotonic() + timeout
            for name in group:
                p = self.children[name].proc
                if p is None:
                    continue
                try:
                    codes[name] = p.wait(max(0.1, deadline - time.monotonic()))
                except subprocess.TimeoutExpired:
                    p.kill()
                    codes[name] = p.wait()
        return codes
