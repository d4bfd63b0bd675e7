"""Counters that survive restarts: the supervisor's totals of each service over all of
its processes (a restarted process counts from zero again; its predecessor's last
status is added to the total).

Anyone on the bus can answer a status query in a process's name. The totals therefore
believe of each process (pid and host, which the supervisor checks are its own child's)
only what its own reply also says: when several replies claim one process, each counter
is their smallest (:func:`least`; the genuine reply is among them, so a forged one can
lower a count for one poll but never raise it), and a process is its pid and host alone
(a reply with another start time cannot make the process's counts "finished" and
counted twice)."""

from __future__ import annotations

import collections
import threading

import msgspec

from ovis.common.messages import ServiceStatus

__all__ = ["COUNTERS", "CounterTotals", "ServiceTotals", "least"]

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
    """``a`` with each counter the smaller of the two replies' (errors by kind too)."""
    errors = {k: min(n, b.errors.get(k, 0)) for k, n in a.errors.items() if k in b.errors}
    smaller = {name: min(getattr(a, name), getattr(b, name)) for name in COUNTERS}
    return msgspec.structs.replace(a, errors=errors, **smaller)


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
