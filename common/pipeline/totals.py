"""Counters that survive restarts: the supervisor's totals of each service over all of
its processes (a restarted process counts from zero again; its predecessor's last
status is added to the total).

Anyone on the bus can answer a status query in a process's name. The totals therefore
believe of each process (pid and host, which the supervisor checks are its own child's)
only what its own reply also says: when several replies claim one process, each counter
is their smallest (:func:`least`; the genuine reply is among them, so a forged one can
lower a count for one poll but never raise it), and a process is its pid and host alone
(a reply with another start time cannot make the process's counts "finished" and
counted twice). Replies that claim one process and differ are themselves the sign of a
forger (a process answers a query once): :func:`claimed_once` then says so in the
state, never better than the worse of them."""

from __future__ import annotations

import collections
import threading

import msgspec

from ovis.common.messages import IDLE_STATES, SOURCE_LOST, ServiceStatus

__all__ = ["COUNTERS", "CounterTotals", "ServiceTotals", "claimed_once", "least"]

#: The counters a status carries that the totals add up.
COUNTERS = ("frames_in", "frames_out", "dropped", "seq_jumps", "stream_restarts")


class ServiceTotals(msgspec.Struct, kw_only=True):
    """One service's counters summed over its processes (``processes``: how many were
    seen)."""

    frames_in: int = 0
    frames_out: int = 0
    dropped: int = 0
    seq_jumps: int = 0
    stream_restarts: int = 0
    errors: dict[str, int] = {}
    processes: int = 0


def _add(total: ServiceTotals, status: ServiceStatus) -> ServiceTotals:
    errors = collections.Counter(total.errors)
    errors.update(status.errors)
    sums = {name: getattr(total, name) + getattr(status, name) for name in COUNTERS}
    return ServiceTotals(errors=dict(errors), processes=total.processes + 1, **sums)


def least(a: ServiceStatus, b: ServiceStatus) -> ServiceStatus:
    """``a`` with each counter the smaller of the two replies' (errors by kind too), and
    the capture stream identity of either where ``a`` names none: a reply copied before
    the process saw its first frame (no stream yet) must not take away the stream its
    frames are counted under (``ovis up`` would count none of them)."""
    errors = {k: min(n, b.errors.get(k, 0)) for k, n in a.errors.items() if k in b.errors}
    smaller = {name: min(getattr(a, name), getattr(b, name)) for name in COUNTERS}
    return msgspec.structs.replace(a, errors=errors, stream=a.stream or b.stream, **smaller)


def _badness(state: str) -> int:
    """How bad a state is, for two replies that disagree: "ok" 0, idle 1, any other 2,
    failing or the source lost 3 (``ovis up`` then exits non-zero)."""
    if state == "ok":
        return 0
    if state in ("failing", SOURCE_LOST):
        return 3
    return 1 if state.startswith(IDLE_STATES) else 2


def claimed_once(a: ServiceStatus, b: ServiceStatus) -> ServiceStatus:
    """Two status replies that claim one process (pid and host). The same: that status.
    Different: another client answers in its name, and which reply is genuine cannot be
    told: counts the smaller (:func:`least`), the state the worse of the two and at
    least "degraded", and the reason says both (a forged "ok" never hides a failing
    stage, nor a lost source)."""
    if a == b:
        return a
    merged = least(a, b)
    worse = max((a, b), key=lambda s: _badness(s.state))
    state = worse.state if _badness(worse.state) >= 2 else "degraded"
    said = f"{a.state}" + (f" ({a.reason})" if a.reason else "")
    said += f" / {b.state}" + (f" ({b.reason})" if b.reason else "")
    reason = f"two different status answers in its name (another client answers for it): {said}"
    return msgspec.structs.replace(merged, state=state, reason=reason)


class CounterTotals:
    """The last status of each service's current process, and the sum of its earlier
    processes' last statuses (a process is told apart by pid and host). Fed with every
    status poll; what a process counted after its last poll is lost."""

    def __init__(self) -> None:
        self._current: dict[str, ServiceStatus] = {}
        self._finished: dict[str, ServiceTotals] = {}
        self._lock = threading.Lock()

    def record(self, status: ServiceStatus) -> None:
        def process(s: ServiceStatus) -> tuple[int, str]:
            return s.pid, s.host

        with self._lock:
            before = self._current.get(status.service)
            if before is not None and process(before) != process(status):
                done = self._finished.get(status.service, ServiceTotals())
                self._finished[status.service] = _add(done, before)
            self._current[status.service] = status

    def totals(self) -> dict[str, ServiceTotals]:
        """Every service's counters over all its processes."""
        with self._lock:
            names = self._current.keys() | self._finished.keys()
            out = {}
            for name in sorted(names):
                total = self._finished.get(name, ServiceTotals())
                current = self._current.get(name)
                out[name] = _add(total, current) if current is not None else total
            return out
