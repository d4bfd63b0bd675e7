"""The supervisor's restart rule: a process that dies is restarted at once the first
time, then after a back-off (doubling from :data:`BACKOFF_START_S` up to
:data:`BACKOFF_MAX_S`; all reset once it has run well for :data:`HEALTHY_S`) while its
budget lasts (``max_restarts`` within ``window_s``). The first restart costs only the
process's start; a process that keeps dying waits 1, 2, 4 … s."""

from __future__ import annotations

import signal
from collections import deque

__all__ = ["BACKOFF_MAX_S", "BACKOFF_START_S", "HEALTHY_S", "RestartBudget", "describe_exit"]

BACKOFF_START_S = 1.0
BACKOFF_MAX_S = 10.0
#: A process that has run this long has recovered: its back-off starts again.
HEALTHY_S = 30.0


def describe_exit(code: int) -> str:
    """'exit code 3' or 'killed by SIGKILL' (a negative code is the signal)."""
    if code < 0:
        try:
            return f"killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exit code {code}"


class RestartBudget:
    """The restarts of one process: how many, the recent ones, the current back-off."""

    def __init__(self, max_restarts: int, window_s: float) -> None:
        self.max_restarts = max_restarts
        self.window_s = window_s
        self.restarts = 0
        self.recent: deque[float] = deque(maxlen=64)
        self.backoff = 0.0  # the first restart is immediate

    def running(self, now: float, started_at: float) -> None:
        """The process is alive at ``now``: a long enough run resets the back-off."""
        if now - started_at > HEALTHY_S:
            self.backoff = 0.0

    def died(self, now: float) -> float | None:
        """The process died at ``now``: the back-off to wait before restarting it (and the
        next one doubles), or None when its budget is used up."""
        while self.recent and now - self.recent[0] > self.window_s:
            self.recent.popleft()
        if len(self.recent) >= self.max_restarts:
            return None
        delay = self.backoff
        self.backoff = min(BACKOFF_MAX_S, 2 * delay) if delay else BACKOFF_START_S
        return delay

    def restarted(self, now: float) -> None:
        self.restarts += 1
        self.recent.append(now)
